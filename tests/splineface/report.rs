//! Overlays and `report.html` without a browser: sizes, where the marks land, what the page
//! holds for any subset of the outputs, and text escaped. (`report_page.rs` opens the page
//! in Chromium.)

use std::path::PathBuf;

use nalgebra::Point2;
use splineface::report::{
    MAX_SIDE, MIN_SIDE, Overlay, PageOptions, PhotoStatus, draw_overlay, overlay_scale, report_page,
};

fn overlay<'a>(image: &'a image::RgbImage, status: &'a PhotoStatus) -> Overlay<'a> {
    Overlay {
        image,
        name: "photo",
        status,
        notes: &[],
        face_box: None,
        landmarks: &[],
        fitted: None,
    }
}

/// The caption band's height: what the overlay adds above the scaled photo.
fn band(picture: &image::RgbImage, photo: (u32, u32)) -> u32 {
    let scale = overlay_scale(photo.0, photo.1);
    picture.height() - (f64::from(photo.1) * scale).round() as u32
}

#[test]
fn overlays_are_scaled_into_a_legible_range_whatever_the_photo() {
    let used = PhotoStatus::Used;
    for (w, h) in [(40, 30), (1, 1), (800, 1000), (4000, 3000), (9000, 50)] {
        let photo = image::RgbImage::from_pixel(w, h, image::Rgb([90, 90, 90]));
        let picture = draw_overlay(&overlay(&photo, &used));
        let scale = overlay_scale(w, h);
        let width = ((f64::from(w) * scale).round() as u32).max(1);
        assert_eq!(picture.width(), width, "{w}×{h}");
        let long = (f64::from(w.max(h)) * scale).round() as u32;
        if w.max(h) > MAX_SIDE {
            assert_eq!(long, MAX_SIDE);
        } else if w.max(h) < MIN_SIDE {
            assert_eq!(long, MIN_SIDE);
        } else {
            assert_eq!(long, w.max(h));
        }
        assert!(band(&picture, (w, h)) >= 30, "a caption band above the photo");
    }
    // A greyscale photo, as the program decodes it.
    let grey = image::DynamicImage::ImageLuma8(image::GrayImage::from_pixel(640, 480, image::Luma([120])));
    let picture = draw_overlay(&overlay(&grey.to_rgb8(), &used));
    assert_eq!(picture.width(), 640);
}

#[test]
fn marks_land_where_the_points_are() {
    // A black 1000 × 800 photo (scale 1): a landmark at (300, 200), a fitted point at
    // (600, 500) whose photo point is at (600, 400), a face box from (100, 100), 500 wide.
    let photo = image::RgbImage::new(1000, 800);
    let landmarks = [Point2::new(300.0, 200.0)];
    let given = [Point2::new(600.0, 400.0)];
    let fitted = [Point2::new(600.0, 500.0)];
    let status = PhotoStatus::Used;
    let picture = draw_overlay(&Overlay {
        face_box: Some([100.0, 100.0, 500.0, 500.0]),
        landmarks: &landmarks,
        fitted: Some((&given, &fitted)),
        ..overlay(&photo, &status)
    });
    let top = band(&picture, (1000, 800));
    let at = |x: u32, y: u32| picture.get_pixel(x, y + top).0;
    let green = at(300, 200);
    assert!(green[1] > 200 && green[0] < 120, "landmark: {green:?}");
    let magenta = at(600, 500);
    assert!(
        magenta[0] > 200 && magenta[2] > 150 && magenta[1] < 100,
        "fitted: {magenta:?}"
    );
    // The residual line runs from the photo's point to the fitted one.
    let line = at(600, 450);
    assert!(line[0] > 150, "residual: {line:?}");
    let yellow = at(350, 100);
    assert!(
        yellow[0] > 200 && yellow[1] > 150 && yellow[2] < 60,
        "box: {yellow:?}"
    );
    // Away from every mark the photo is untouched.
    assert_eq!(at(800, 700), [0, 0, 0]);
    assert_eq!(at(450, 300), [0, 0, 0]);
}

#[test]
fn the_caption_shows_the_status_in_its_colour() {
    let photo = image::RgbImage::new(600, 400);
    let reddish = |picture: &image::RgbImage, top: u32| {
        (0..top)
            .flat_map(|y| (0..picture.width()).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let p = picture.get_pixel(x, y).0;
                p[0] > 200 && p[1] < 150 && p[2] < 140
            })
            .count()
    };
    let skipped = PhotoStatus::Skipped("no face found".into());
    let used = PhotoStatus::Used;
    let a = draw_overlay(&overlay(&photo, &skipped));
    let b = draw_overlay(&overlay(&photo, &used));
    assert!(
        reddish(&a, band(&a, (600, 400))) > 50,
        "the skipped reason is drawn in red"
    );
    assert_eq!(reddish(&b, band(&b, (600, 400))), 0);
    // A long reason wraps instead of running off the picture: the band grows.
    let long = PhotoStatus::Dropped("its landmarks do not mark the places the other photos' do ".repeat(6));
    let c = draw_overlay(&overlay(&photo, &long));
    assert!(band(&c, (600, 400)) > band(&a, (600, 400)) + 40);
}

fn options() -> PageOptions {
    PageOptions {
        title: "a <test> & more".into(),
        reconstruction: PathBuf::new(),
        comparison: None,
    }
}

#[test]
fn a_page_of_no_outputs_says_what_is_missing_and_carries_no_viewer() {
    let page = report_page(&[], &options());
    assert!(page.starts_with("<!doctype html>"));
    assert!(page.contains("<title>a &lt;test&gt; &amp; more</title>"));
    assert!(page.contains("No report.json") && page.contains("No face.glb"));
    assert!(!page.contains("model-viewer id=\"viewer\""));
    assert!(
        page.len() < 50_000,
        "no viewer script without a face: {} bytes",
        page.len()
    );
    assert!(page.trim_end().ends_with("</html>"));
}

#[test]
fn a_page_escapes_what_the_report_says_and_tolerates_broken_files() {
    let report = serde_json::json!({
        "photos_used": ["<img src=x onerror=alert(1)>"],
        "photos_dropped": [{ "name": "b", "reason": "a </table> in a reason" }],
        "photos_skipped": ["c.jpg: no face found"],
        "warnings": ["<script>alert(2)</script>"],
        "timings": [{ "stage": "depth", "ms": 12.5 }],
    });
    let files = vec![
        (PathBuf::from("report.json"), serde_json::to_vec(&report).unwrap()),
        (PathBuf::from("structure.json"), b"{ not json".to_vec()),
        (PathBuf::from("preview.png"), b"not a png".to_vec()),
        (PathBuf::from("overlays/c.jpg"), b"not a jpeg either".to_vec()),
    ];
    let page = report_page(&files, &options());
    assert!(!page.contains("<img src=x"));
    assert!(!page.contains("<script>alert"));
    assert!(page.contains("&lt;script&gt;alert(2)&lt;/script&gt;"));
    assert!(page.contains("a &lt;/table&gt; in a reason"));
    assert!(page.contains("no face found"));
    assert!(page.contains("1 photo used, 1 dropped, 1 skipped"));
    // The broken pictures are still inlined (the browser's self-check reports them).
    assert_eq!(page.matches("data:image/png;base64,").count(), 2);
}

#[test]
fn a_page_of_the_demo_inlines_the_face_the_viewer_and_every_picture() {
    let scene = splineface::demo::scene(&splineface::demo::SceneOptions {
        photos: 3,
        ..splineface::demo::SceneOptions::default()
    })
    .unwrap();
    let result = splineface::pipeline::reconstruct(
        &scene.inputs,
        splineface::reference::ReferenceFace::embedded(),
        &splineface::pipeline::PipelineOptions::default(),
        |_| {},
    )
    .unwrap();
    let files = result.files().unwrap();
    let page = report_page(&files, &options());
    let glb = files.iter().find(|(p, _)| p.as_os_str() == "face.glb").unwrap();
    assert!(page.contains(&format!(
        "data:model/gltf-binary;base64,{}",
        base64::encode(&glb.1)
    )));
    assert!(page.contains("<model-viewer id=\"viewer\""));
    // The viewer's script is inlined whole.
    assert!(page.contains("ModelViewerElement") && page.len() > 1_000_000);
    // RASL's six pictures, the texture's three, the depth map, the consistency map and the
    // preview.
    let pictures = page.matches("data:image/").count();
    assert!(pictures >= 11, "{pictures} pictures");
    // One row per photo, with its pose.
    assert_eq!(page.matches("<td class=\"used\">used</td>").count(), 3);
    // The face fit's residual is in structure.json and on the page.
    assert_eq!(result.photo_fits.len(), 3);
    for fit in &result.photo_fits {
        assert!(
            fit.rms_pixels.is_finite() && fit.rms_pixels < 20.0,
            "{}",
            fit.rms_pixels
        );
        assert!(page.contains(&format!("{:.2}", fit.rms_pixels)));
    }
}
