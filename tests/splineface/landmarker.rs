//! The dlib shape_predictor runtime: damaged files are errors; with `../shared`, the peer's
//! fixture is reproduced.

use std::path::Path;

use splineface::landmarker::{COMPACT_MAGIC, FaceBox, Intensity, ModelProblem, ModelSource, ShapePredictor};

/// dlib's integer encoding.
fn int(out: &mut Vec<u8>, value: i64) {
    let (neg, mut magnitude) = (value < 0, value.unsigned_abs());
    let mut body = Vec::new();
    loop {
        body.push((magnitude & 0xff) as u8);
        magnitude >>= 8;
        if magnitude == 0 {
            break;
        }
    }
    out.push(body.len() as u8 | if neg { 0x80 } else { 0 });
    out.extend(body);
}

/// dlib's float encoding, exact for values with few bits.
fn float(out: &mut Vec<u8>, value: f32) {
    let exponent = -16;
    let mantissa = (f64::from(value) * 65536.0).round() as i64;
    int(out, mantissa);
    int(out, exponent);
}

fn column(out: &mut Vec<u8>, values: &[f32]) {
    int(out, -(values.len() as i64));
    int(out, -1);
    for &v in values {
        float(out, v);
    }
}

/// A two-point model with one cascade of one tree of depth 1 that moves both points by
/// (+0.25, 0) when pixel A is brighter than pixel B by more than 10, else by (−0.25, 0).
fn tiny_model() -> Vec<u8> {
    let mut m = Vec::new();
    int(&mut m, 1);
    column(&mut m, &[0.25, 0.5, 0.75, 0.5]);
    int(&mut m, 1); // cascades
    int(&mut m, 1); // trees
    int(&mut m, 1); // splits
    int(&mut m, 0);
    int(&mut m, 1);
    float(&mut m, 10.0);
    int(&mut m, 2); // leaves
    column(&mut m, &[0.25, 0.0, 0.25, 0.0]);
    column(&mut m, &[-0.25, 0.0, -0.25, 0.0]);
    int(&mut m, 1); // anchor sets
    int(&mut m, 2);
    int(&mut m, 0);
    int(&mut m, 1);
    int(&mut m, 1); // delta sets
    int(&mut m, 2);
    float(&mut m, 0.0);
    float(&mut m, 0.0);
    float(&mut m, 0.0);
    float(&mut m, 0.0);
    m
}

#[test]
fn a_hand_made_model_runs_as_specified() {
    let model = ShapePredictor::parse(&tiny_model()).unwrap();
    assert_eq!(model.points(), 2);
    // Box (10, 20)–(50, 60): the mean shape's points land at (20, 40) and (40, 40).
    let face = FaceBox::from_size(10, 20, 41, 41);
    for (left_bright, shift) in [(true, 0.25), (false, -0.25)] {
        let image = image::RgbImage::from_fn(64, 64, |x, _| {
            let bright = if x < 30 { left_bright } else { !left_bright };
            image::Rgb(if bright { [200, 100, 0] } else { [10, 20, 30] })
        });
        let points = model.predict(&Intensity::from_rgb(&image), face);
        let expected = [(20.0 + 40.0 * shift, 40.0), (40.0 + 40.0 * shift, 40.0)];
        for (p, e) in points.iter().zip(expected) {
            assert!(
                (p.x - e.0).abs() < 1e-4 && (p.y - e.1).abs() < 1e-4,
                "{p} vs {e:?}"
            );
        }
    }
}

/// Faces landmarked together are landmarked as alone, bit for bit: the hand-made model on two
/// images that send its tree opposite ways, and dlib's model (when `../shared` is there, as in
/// the ignored fixture test) on several faces and boxes.
#[test]
fn faces_landmarked_together_are_landmarked_as_alone() {
    let model = ShapePredictor::parse(&tiny_model()).unwrap();
    let images: Vec<Intensity> = [true, false]
        .map(|left_bright| {
            Intensity::from_rgb(&image::RgbImage::from_fn(64, 64, |x, _| {
                let bright = if x < 30 { left_bright } else { !left_bright };
                image::Rgb(if bright { [200, 100, 0] } else { [10, 20, 30] })
            }))
        })
        .into();
    let faces = [
        (&images[0], FaceBox::from_size(10, 20, 41, 41)),
        (&images[1], FaceBox::from_size(10, 20, 41, 41)),
        (&images[0], FaceBox::from_size(-5, 3, 30, 50)),
    ];
    let together = model.predict_all(&faces);
    assert_eq!(together.len(), 3);
    assert_ne!(
        together[0], together[1],
        "the two images send the tree opposite ways"
    );
    for (points, &(image, face)) in together.iter().zip(&faces) {
        assert_eq!(points, &model.predict(image, face));
    }
    assert!(model.predict_all(&[]).is_empty());
}

/// The mirrored intensity is the intensity of the mirrored photo, pixel for pixel (odd and
/// even widths, one-pixel images).
#[test]
fn the_mirrored_intensity_is_the_mirrored_photos() {
    for (w, h) in [(7, 5), (8, 3), (1, 4), (5, 1)] {
        let image = image::RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([
                (x * 37 + y * 11) as u8,
                (x * 5 + y * 71) as u8,
                (x * y * 13 + 7) as u8,
            ])
        });
        let mirrored = Intensity::from_rgb(&image).mirrored();
        let expected = Intensity::from_rgb(&image::imageops::flip_horizontal(&image));
        assert_eq!(mirrored, expected, "{w} × {h}");
    }
}

/// dlib's 68-point model and the folder of its fixture, from `../shared`.
fn dlib_model_and_fixture() -> (ShapePredictor, std::path::PathBuf) {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let model = ShapePredictor::read(&shared.join("models/shape_predictor_68_face_landmarks.dat")).unwrap();
    (model, shared.join("data/dlib-faces"))
}

/// dlib's model on the fixture's faces, together and alone.
#[test]
#[ignore = "needs ../shared (the model and dlib's fixture)"]
fn dlibs_model_landmarks_faces_together_as_alone() {
    let (model, dir) = dlib_model_and_fixture();
    let text = std::fs::read_to_string(dir.join("testing_with_face_landmarks.xml")).unwrap();
    let mut images = std::collections::BTreeMap::new();
    let faces: Vec<(String, FaceBox)> = fixture(&text)
        .into_iter()
        .map(|(file, face, _)| (file, face))
        .collect();
    for (file, _) in &faces {
        images
            .entry(file.clone())
            .or_insert_with(|| Intensity::from_rgb(&image::open(dir.join(file)).unwrap().to_rgb8()));
    }
    // Each face from its box and from the box shifted by a fifth of its width.
    let jobs: Vec<(&Intensity, FaceBox)> = faces
        .iter()
        .flat_map(|(file, b)| {
            let dx = (b.right - b.left) / 5;
            [
                (&images[file], *b),
                (
                    &images[file],
                    FaceBox {
                        left: b.left + dx,
                        right: b.right + dx,
                        ..*b
                    },
                ),
            ]
        })
        .collect();
    assert!(jobs.len() >= 10, "{} faces", jobs.len());
    let together = model.predict_all(&jobs);
    for (points, &(image, face)) in together.iter().zip(&jobs) {
        assert_eq!(points, &model.predict(image, face));
    }
}

#[test]
fn damaged_models_are_errors() {
    let good = tiny_model();
    for cut in [0, 1, 5, good.len() / 2, good.len() - 1] {
        assert!(
            matches!(
                ShapePredictor::parse(&good[..cut]),
                Err(ModelProblem::Truncated(_) | ModelProblem::Malformed { .. })
            ),
            "cut at {cut}"
        );
    }
    // A length claiming 10¹² items is refused before allocating.
    let mut huge = Vec::new();
    int(&mut huge, 1);
    column(&mut huge, &[0.25, 0.5]);
    int(&mut huge, 1_000_000_000_000);
    assert!(matches!(
        ShapePredictor::parse(&huge),
        Err(ModelProblem::Malformed { .. })
    ));
    // Counts that each fit the file but whose product does not: a 1 MB model with a mean
    // shape of 200,000 values and a tree of 100,000 splits. The leaves' storage was reserved
    // as leaves × shape values (2·10¹⁰ floats, an allocation failure that aborts); it is now
    // bounded by the file, and the missing leaves are an error.
    let mut product = Vec::new();
    int(&mut product, 1);
    int(&mut product, 200_000);
    int(&mut product, 1);
    for _ in 0..200_000 {
        int(&mut product, 0);
        int(&mut product, 0);
    }
    int(&mut product, 1); // cascades
    int(&mut product, 1); // trees
    int(&mut product, 100_000); // splits
    for _ in 0..100_000 {
        for _ in 0..4 {
            int(&mut product, 0);
        }
    }
    int(&mut product, 100_001); // leaves
    product.extend(std::iter::repeat_n(0, 2 * 100_001)); // room enough for that count
    assert!(product.len() < 2_000_000);
    assert!(matches!(
        ShapePredictor::parse(&product),
        Err(ModelProblem::Truncated(_) | ModelProblem::Malformed { .. })
    ));
    // Another version.
    let mut other = good.clone();
    other[1] = 2;
    assert!(ShapePredictor::parse(&other).is_err());
    // A bad control byte.
    let mut bad = good.clone();
    bad[0] = 0x7f;
    assert!(ShapePredictor::parse(&bad).is_err());
    let missing = ShapePredictor::read(Path::new("/nonexistent/model.dat")).unwrap_err();
    assert!(missing.to_string().contains("model.dat"));
}

#[test]
fn the_compact_form_holds_the_same_model_and_refuses_damage() {
    let dat = tiny_model();
    let model = ShapePredictor::parse(&dat).unwrap();
    let source = ModelSource::of(&dat);
    let compact = model.to_compact(source);
    assert!(compact.starts_with(COMPACT_MAGIC));
    // The same model, and the source it came from.
    let (again, recorded) = ShapePredictor::read_compact(compact.as_slice(), compact.len() as u64).unwrap();
    assert_eq!(again, model);
    assert_eq!(recorded, source);
    // read() tells the forms apart by their first bytes.
    let dir = std::env::temp_dir().join(format!("splineface-compact-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("model.sfsp"), &compact).unwrap();
    std::fs::write(dir.join("model.dat"), &dat).unwrap();
    assert_eq!(ShapePredictor::read(&dir.join("model.sfsp")).unwrap(), model);
    assert_eq!(ShapePredictor::read(&dir.join("model.dat")).unwrap(), model);
    // Every cut is an error, never a panic.
    for cut in 0..compact.len() {
        let damaged = &compact[..cut];
        assert!(
            ShapePredictor::read_compact(damaged, damaged.len() as u64).is_err(),
            "cut at {cut}"
        );
    }
    // The same through files (read() reads a file's leaves after the rest, in parallel).
    for cut in 0..compact.len() {
        std::fs::write(dir.join("cut.sfsp"), &compact[..cut]).unwrap();
        let outcome = ShapePredictor::read(&dir.join("cut.sfsp"));
        assert!(outcome.is_err(), "cut at {cut}");
    }
    // Bytes after the end, a count beyond the file, an anchor or a split index out of range.
    let mut longer = compact.clone();
    longer.push(0);
    assert!(ShapePredictor::read_compact(longer.as_slice(), longer.len() as u64).is_err());
    let header = 16 + 16; // magic, source
    let mut huge = compact.clone();
    huge[header + 4..header + 8].copy_from_slice(&u32::MAX.to_le_bytes()); // cascades
    assert!(ShapePredictor::read_compact(huge.as_slice(), huge.len() as u64).is_err());
    let first_anchor = header + 8 + 4 * 4 + 4; // counts, mean shape, feature count
    let mut anchor = compact.clone();
    anchor[first_anchor..first_anchor + 4].copy_from_slice(&7u32.to_le_bytes());
    let error = ShapePredictor::read_compact(anchor.as_slice(), anchor.len() as u64).unwrap_err();
    assert!(error.to_string().contains("anchor"), "{error}");
    let first_split = first_anchor + 2 * 4 + 4 * 4 + 4 + 4; // anchors, deltas, tree count, split count
    let mut split = compact.clone();
    split[first_split..first_split + 4].copy_from_slice(&2u32.to_le_bytes());
    let error = ShapePredictor::read_compact(split.as_slice(), split.len() as u64).unwrap_err();
    assert!(error.to_string().contains("feature pixel"), "{error}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
#[ignore = "needs ../shared (the model)"]
fn the_compact_form_of_dlibs_model_is_the_same_model() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let path = shared.join("models/shape_predictor_68_face_landmarks.dat");
    let dat = std::fs::read(&path).unwrap();
    let model = ShapePredictor::parse(&dat).unwrap();
    let compact = model.to_compact(ModelSource::of(&dat));
    let (again, source) = ShapePredictor::read_compact(compact.as_slice(), compact.len() as u64).unwrap();
    assert_eq!(source.bytes, dat.len() as u64);
    assert!(
        again == model,
        "the compact form holds the same trees, bit for bit"
    );
    let file = std::env::temp_dir().join(format!("splineface-dlib-{}.sfsp", std::process::id()));
    std::fs::write(&file, &compact).unwrap();
    let read = ShapePredictor::read(&file);
    std::fs::remove_file(&file).unwrap();
    assert!(read.unwrap() == model, "read from a file, the same trees");
    println!(
        "dlib's model: {} bytes as .dat, {} in the compact form",
        dat.len(),
        compact.len()
    );
}

/// One face of the fixture: the image file, the box, dlib's 68 points.
type FixtureFace = (String, FaceBox, Vec<(f64, f64)>);

/// The boxes and dlib's own 68 points from the fixture's XML.
fn fixture(xml: &str) -> Vec<FixtureFace> {
    let attribute = |tag: &str, name: &str| -> Option<String> {
        let start = tag.find(&format!("{name}='"))? + name.len() + 2;
        let end = tag[start..].find('\'')? + start;
        Some(tag[start..end].to_owned())
    };
    let mut faces = Vec::new();
    let mut file = String::new();
    let mut current: Option<(FaceBox, Vec<(f64, f64)>)> = None;
    for line in xml.lines().map(str::trim) {
        if line.starts_with("<image ") {
            file = attribute(line, "file").unwrap();
        } else if line.starts_with("<box ") {
            let n = |k| attribute(line, k).unwrap().parse::<i64>().unwrap();
            current = Some((
                FaceBox::from_size(n("left"), n("top"), n("width"), n("height")),
                Vec::new(),
            ));
        } else if line.starts_with("<part ") {
            let n = |k| attribute(line, k).unwrap().parse::<f64>().unwrap();
            current.as_mut().unwrap().1.push((n("x"), n("y")));
        } else if line.starts_with("</box>") {
            let (face, parts) = current.take().unwrap();
            faces.push((file.clone(), face, parts));
        }
    }
    faces
}

#[test]
#[ignore = "needs ../shared (the model and dlib's fixture)"]
fn dlibs_own_points_are_reproduced() {
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    let start = std::time::Instant::now();
    let model = ShapePredictor::read(&shared.join("models/shape_predictor_68_face_landmarks.dat")).unwrap();
    let load = start.elapsed();
    assert_eq!(model.points(), 68);
    let dir = shared.join("data/dlib-faces");
    let mut errors = Vec::new();
    let mut elapsed = std::time::Duration::ZERO;
    let mut exact = 0usize;
    for xml in [
        "training_with_face_landmarks.xml",
        "testing_with_face_landmarks.xml",
    ] {
        let text = std::fs::read_to_string(dir.join(xml)).unwrap();
        for (file, face, parts) in fixture(&text) {
            let image = image::open(dir.join(&file)).unwrap().to_rgb8();
            let intensity = Intensity::from_rgb(&image);
            let t = std::time::Instant::now();
            let points = model.predict(&intensity, face);
            elapsed += t.elapsed();
            let mean = points
                .iter()
                .zip(&parts)
                .map(|(p, q)| ((p.x - q.0).powi(2) + (p.y - q.1).powi(2)).sqrt())
                .sum::<f64>()
                / 68.0;
            exact += points
                .iter()
                .zip(&parts)
                .filter(|(p, q)| p.x.round() == q.0 && p.y.round() == q.1)
                .count();
            errors.push((file, mean));
        }
    }
    let overall = errors.iter().map(|e| e.1).sum::<f64>() / errors.len() as f64;
    println!(
        "{} faces: mean error {overall:.3} px (worst {:.3}), {:.1}% of the points exact after rounding; model load {:.2} s, {:.2} ms a face",
        errors.len(),
        errors.iter().map(|e| e.1).fold(0.0, f64::max),
        100.0 * exact as f64 / (68 * errors.len()) as f64,
        load.as_secs_f64(),
        1e3 * elapsed.as_secs_f64() / errors.len() as f64
    );
    assert!(errors.len() >= 10);
    assert!(overall < 1.0, "mean error {overall} px: {errors:?}");
}

fn iou(a: &FaceBox, b: &FaceBox) -> f64 {
    let w = (a.right.min(b.right) - a.left.max(b.left) + 1).max(0);
    let h = (a.bottom.min(b.bottom) - a.top.max(b.top) + 1).max(0);
    let area = |r: &FaceBox| (r.right - r.left + 1) * (r.bottom - r.top + 1);
    let inter = (w * h) as f64;
    inter / ((area(a) + area(b)) as f64 - inter).max(1.0)
}

/// Detection on dlib's fixture: every face dlib found is found, the calibrated boxes give
/// dlib's points, the dogs have no face and the bald guys many.
#[test]
#[ignore = "needs ../shared (the model and dlib's fixture)"]
fn detection_and_landmarks_on_the_fixture() {
    use splineface::detect::{BOX_CALIBRATION, detect_faces, landmark_box};
    let (model, dir) = dlib_model_and_fixture();
    let mut pairs = Vec::new();
    let (mut found, mut total) = (0, 0);
    let mut errors = (Vec::new(), Vec::new());
    let mut detect_time = std::time::Duration::ZERO;
    for xml in [
        "training_with_face_landmarks.xml",
        "testing_with_face_landmarks.xml",
    ] {
        let text = std::fs::read_to_string(dir.join(xml)).unwrap();
        for (file, face, parts) in fixture(&text) {
            total += 1;
            let image = image::open(dir.join(&file)).unwrap();
            let t = std::time::Instant::now();
            let detections = detect_faces(&image.to_luma8());
            detect_time += t.elapsed();
            let Some(best) = detections
                .iter()
                .max_by(|a, b| iou(&a.bbox, &face).total_cmp(&iou(&b.bbox, &face)))
                .filter(|d| iou(&d.bbox, &face) > 0.3)
            else {
                continue;
            };
            found += 1;
            pairs.push((best.bbox, face));
            let intensity = Intensity::from_rgb(&image.to_rgb8());
            let error = |points: Vec<nalgebra::Point2<f64>>| {
                points
                    .iter()
                    .zip(&parts)
                    .map(|(p, q)| ((p.x - q.0).powi(2) + (p.y - q.1).powi(2)).sqrt())
                    .sum::<f64>()
                    / 68.0
                    / (face.right - face.left + 1) as f64
            };
            errors.0.push(error(model.predict(&intensity, best.bbox)));
            errors
                .1
                .push(error(model.predict(&intensity, landmark_box(best))));
        }
    }
    // The calibration that would fit these pairs best.
    let n = pairs.len() as f64;
    let mut fit = [0.0; 4];
    for (s, d) in &pairs {
        let (w, h) = ((s.right - s.left + 1) as f64, (s.bottom - s.top + 1) as f64);
        fit[0] += (d.left - s.left) as f64 / w / n;
        fit[1] += (d.top - s.top) as f64 / h / n;
        fit[2] += (d.right - d.left + 1) as f64 / w / n;
        fit[3] += (d.bottom - d.top + 1) as f64 / h / n;
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    println!(
        "detected {found} of {total} fixture faces ({:.1} ms an image); best calibration {fit:?} (in use {BOX_CALIBRATION:?}); \
         landmark error / box width: raw boxes {:.4}, calibrated {:.4}",
        1e3 * detect_time.as_secs_f64() / total as f64,
        mean(&errors.0),
        mean(&errors.1)
    );
    let dogs = detect_faces(&image::open(dir.join("dogs.jpg")).unwrap().to_luma8());
    let bald = detect_faces(&image::open(dir.join("bald_guys.jpg")).unwrap().to_luma8());
    println!(
        "dogs.jpg: {} faces; bald_guys.jpg: {} faces",
        dogs.len(),
        bald.len()
    );
    assert!(found as f64 >= 0.9 * total as f64);
    assert!(
        mean(&errors.1) < 0.037,
        "calibrated landmark error {:.4} of the box width",
        mean(&errors.1)
    );
    assert!(bald.len() >= 5);
}

/// The coarse-first subject search decides every photo of dlib's fixture and of `lps-head` as
/// the full search does: the same subject (boxes overlapping by more than half) or the same
/// refusal (no face, or two faces of about one size).
#[test]
#[ignore = "needs ../shared (dlib's fixture and lps-head's photos)"]
fn the_coarse_subject_search_decides_as_the_full_search() {
    use splineface::detect::{detect_faces, detect_subject_faces, subject_face};
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    let mut photos = Vec::new();
    for dir in ["dlib-faces", "lps-head/photos-8", "lps-head/photos-3"] {
        for entry in std::fs::read_dir(shared.join(dir)).unwrap() {
            let path = entry.unwrap().path();
            if matches!(path.extension().and_then(|e| e.to_str()), Some("jpg" | "png")) {
                photos.push(path);
            }
        }
    }
    photos.sort();
    assert!(photos.len() >= 20, "{} photos", photos.len());
    let (mut full_time, mut coarse_time) = (std::time::Duration::ZERO, std::time::Duration::ZERO);
    let mut subjects = 0;
    for path in &photos {
        let grey = image::open(path).unwrap().to_luma8();
        let t = std::time::Instant::now();
        let full = subject_face(&detect_faces(&grey));
        full_time += t.elapsed();
        let t = std::time::Instant::now();
        let coarse = subject_face(&detect_subject_faces(&grey));
        coarse_time += t.elapsed();
        match (&full, &coarse) {
            (Ok((a, _)), Ok((b, _))) => {
                subjects += 1;
                let overlap = iou(&a.bbox, &b.bbox);
                assert!(
                    overlap > 0.5,
                    "{}: boxes {:?} and {:?} overlap {overlap:.2}",
                    path.display(),
                    a.bbox,
                    b.bbox
                );
            }
            (Err(a), Err(b)) => assert_eq!(
                std::mem::discriminant(a),
                std::mem::discriminant(b),
                "{}: {a} against {b}",
                path.display()
            ),
            _ => panic!(
                "{}: full search {full:?}, coarse-first {coarse:?}",
                path.display()
            ),
        }
    }
    println!(
        "{} photos, {subjects} with a subject; full search {:.0} ms, coarse-first {:.0} ms",
        photos.len(),
        full_time.as_secs_f64() * 1e3,
        coarse_time.as_secs_f64() * 1e3
    );
    assert!(subjects >= 12, "{subjects} photos with a subject");
}

/// The subject among a photo's faces: the only one, the largest when the others are clearly
/// smaller (in any order), none when the two largest are of about one size.
#[test]
fn the_subject_face_is_the_clearly_largest() {
    use splineface::detect::{AMBIGUOUS_FACE_AREA, Detection, SubjectProblem, subject_face};
    let face = |side: i64, left: i64| Detection {
        bbox: FaceBox::from_size(left, 10, side, side),
        score: 5.0,
    };
    assert_eq!(subject_face(&[]), Err(SubjectProblem::NoFace));
    let (only, note) = subject_face(&[face(100, 0)]).unwrap();
    assert_eq!((only, note), (face(100, 0), None));
    // A background face of a third of the width: the largest is used, with a note.
    let (subject, note) = subject_face(&[face(40, 300), face(120, 0), face(30, 500)]).unwrap();
    assert_eq!(subject, face(120, 0));
    assert_eq!(
        note.unwrap(),
        "3 faces found; the largest is used (9.0× the next one's area)"
    );
    // Just under and at the threshold: 70×70 is 0.49 of 100×100, 71×71 is 0.5041.
    const { assert!(0.49 < AMBIGUOUS_FACE_AREA && AMBIGUOUS_FACE_AREA <= 0.5041) };
    assert!(subject_face(&[face(100, 0), face(70, 200)]).is_ok());
    let problem = subject_face(&[face(71, 200), face(100, 0)]).unwrap_err();
    assert_eq!(
        problem,
        SubjectProblem::Ambiguous {
            count: 2,
            first: 10_000,
            second: 5_041
        }
    );
    assert!(problem.to_string().contains("ambiguous"));
}
