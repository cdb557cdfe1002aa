//! The photo stages' speed, each against the way it was done before, in one run: loading
//! dlib's landmark model (its `.dat` parsed against the compact form copied into place),
//! detection (at full size, on a copy scaled to `DETECTION_SIDE`, and the subject's
//! coarse-first search), landmarks (a photo's starts one at a time against together through
//! the trees), and the photos' decoding, detection and landmarks (one after another with
//! full-size detection against in parallel with the coarse-first search).
//!
//! Run: `cargo run --release --example photo_bench -- [--model DAT] [--photos DIR]`
//! (defaults: `../shared/models/shape_predictor_68_face_landmarks.dat` and
//! `../shared/data/lps-head/photos-8`). Prints the figures, best of a few runs each.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use splineface::detect::{
    BOX_SHIFTS, DETECTION_SIDE, detect_faces_within, detect_subject_faces, landmark_box, landmark_face,
    subject_face,
};
use splineface::landmarker::{ModelSource, ShapePredictor};

/// The intersection over union of two boxes.
fn iou(a: splineface::landmarker::FaceBox, b: splineface::landmarker::FaceBox) -> f64 {
    let w = (a.right.min(b.right) - a.left.max(b.left) + 1).max(0);
    let h = (a.bottom.min(b.bottom) - a.top.max(b.top) + 1).max(0);
    let area = |f: splineface::landmarker::FaceBox| (f.right - f.left + 1) * (f.bottom - f.top + 1);
    (w * h) as f64 / (area(a) + area(b) - w * h) as f64
}

/// The best of `runs` timings of `f`, seconds, and its last result.
fn best<T>(runs: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..runs {
        let start = Instant::now();
        let value = f();
        best = best.min(start.elapsed().as_secs_f64());
        last = Some(value);
    }
    (best, last.expect("at least one run"))
}

/// Decodes, detects (searching within `side`, or by the coarse-first subject search when
/// `None`) and landmarks one photo: its 68 points.
fn landmark(path: &Path, model: &ShapePredictor, side: Option<u32>) -> Option<Vec<nalgebra::Point2<f64>>> {
    let image = splineface::align::decode_photo(path).ok()?;
    let grey = image.to_luma8();
    let faces = match side {
        Some(side) => detect_faces_within(&grey, side),
        None => detect_subject_faces(&grey),
    };
    let (face, _) = subject_face(&faces).ok()?;
    landmark_face(model, &image.to_rgb8(), face).ok().map(|f| f.ibug)
}

fn main() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let mut model_path = root.join("models/shape_predictor_68_face_landmarks.dat");
    let mut photo_dir = root.join("data/lps-head/photos-8");
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let mut value = || args.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--model" => model_path = PathBuf::from(value()?),
            "--photos" => photo_dir = PathBuf::from(value()?),
            other => bail!("unknown flag {other}"),
        }
    }
    let mut photos: Vec<PathBuf> = std::fs::read_dir(&photo_dir)
        .with_context(|| format!("cannot read {}", photo_dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| ["png", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    photos.sort();
    if photos.is_empty() {
        bail!("{}: no photos", photo_dir.display());
    }

    // The model.
    let dat = std::fs::read(&model_path).with_context(|| format!("cannot read {}", model_path.display()))?;
    let compact_path = std::env::temp_dir().join(format!("photo-bench-{}.sfsp", std::process::id()));
    std::fs::write(
        &compact_path,
        ShapePredictor::parse(&dat)?.to_compact(ModelSource::of(&dat)),
    )?;
    drop(dat);
    let (dat_s, from_dat) = best(2, || ShapePredictor::read(&model_path));
    let (compact_s, model) = best(5, || ShapePredictor::read(&compact_path));
    let model = model?;
    assert!(from_dat? == model, "the two forms hold the same model");
    std::fs::remove_file(&compact_path)?;
    println!("landmark model");
    println!("  .dat parsed            {:8.1} ms", 1e3 * dat_s);
    println!(
        "  compact form           {:8.1} ms   ({:.1}x faster)",
        1e3 * compact_s,
        dat_s / compact_s
    );

    // Detection, per photo.
    println!("detection ({} photos, {})", photos.len(), photo_dir.display());
    let (mut full_total, mut small_total, mut coarse_total) = (0.0, 0.0, 0.0);
    let (mut one_total, mut together_total) = (0.0, 0.0);
    for path in &photos {
        let image = splineface::align::decode_photo(path)?;
        let grey = image.to_luma8();
        let (full_s, full) = best(2, || detect_faces_within(&grey, u32::MAX));
        let (small_s, small) = best(2, || detect_faces_within(&grey, DETECTION_SIDE));
        let (coarse_s, coarse) = best(2, || detect_subject_faces(&grey));
        full_total += full_s;
        small_total += small_s;
        coarse_total += coarse_s;
        let overlap = |other: &[splineface::detect::Detection]| match (full.first(), other.first()) {
            (Some(a), Some(b)) => format!("{:.3}", iou(a.bbox, b.bbox)),
            _ => "-".to_owned(),
        };
        println!(
            "  {:<14} {}×{}  full {:6.1} ms ({} faces), within {DETECTION_SIDE} px {:6.1} ms (IoU {}), coarse-first {:6.1} ms (IoU {})",
            path.file_name().unwrap_or_default().to_string_lossy(),
            grey.width(),
            grey.height(),
            1e3 * full_s,
            full.len(),
            1e3 * small_s,
            overlap(&small),
            1e3 * coarse_s,
            overlap(&coarse),
        );
        // The landmarks' starts on this photo: the shifted boxes, one at a time and together.
        if let Some(face) = full.first() {
            let start = landmark_box(face);
            let intensity = splineface::landmarker::Intensity::from_rgb(&image.to_rgb8());
            let boxes: Vec<_> = BOX_SHIFTS
                .iter()
                .map(|s| {
                    let dx = (s * (start.right - start.left) as f64).round() as i64;
                    splineface::landmarker::FaceBox {
                        left: start.left + dx,
                        right: start.right + dx,
                        ..start
                    }
                })
                .collect();
            let jobs: Vec<_> = boxes.iter().map(|&b| (&intensity, b)).collect();
            let (one_s, one) = best(3, || {
                jobs.iter().map(|&(i, b)| model.predict(i, b)).collect::<Vec<_>>()
            });
            let (together_s, together) = best(3, || model.predict_all(&jobs));
            assert!(one == together, "together as alone");
            one_total += one_s;
            together_total += together_s;
        }
    }
    println!(
        "  total                  {:8.1} ms full size, {:.1} ms within {DETECTION_SIDE} px ({:.1}x faster), {:.1} ms coarse-first ({:.1}x faster)",
        1e3 * full_total,
        1e3 * small_total,
        full_total / small_total,
        1e3 * coarse_total,
        full_total / coarse_total
    );
    println!(
        "landmarks: {} starts a photo, one at a time {:.1} ms, together {:.1} ms ({:.1}x faster; the same points)",
        BOX_SHIFTS.len(),
        1e3 * one_total,
        1e3 * together_total,
        one_total / together_total
    );

    // The photos' stage: decoding, detection and landmarks.
    let (before_s, before) = best(2, || {
        photos
            .iter()
            .map(|p| landmark(p, &model, Some(u32::MAX)))
            .collect::<Vec<_>>()
    });
    let (after_s, after) = best(2, || {
        photos
            .par_iter()
            .map(|p| landmark(p, &model, None))
            .collect::<Vec<_>>()
    });
    let mut shifts = Vec::new();
    for (a, b) in before.iter().zip(&after) {
        if let (Some(a), Some(b)) = (a, b) {
            shifts.push(a.iter().zip(b).map(|(p, q)| (p - q).norm()).sum::<f64>() / a.len() as f64);
        }
    }
    println!("photos: decoding, detection, landmarks");
    println!(
        "  one after another, full-size detection {:8.1} ms",
        1e3 * before_s
    );
    println!(
        "  in parallel ({} threads), coarse-first detection {:8.1} ms   ({:.1}x faster)",
        rayon::current_num_threads(),
        1e3 * after_s,
        before_s / after_s
    );
    println!(
        "  landmarks moved by the coarse-first detection's boxes: mean {:.2} px, largest photo mean {:.2} px ({} of {} photos landmarked both ways)",
        shifts.iter().sum::<f64>() / shifts.len().max(1) as f64,
        shifts.iter().copied().fold(0.0, f64::max),
        shifts.len(),
        photos.len()
    );
    Ok(())
}
