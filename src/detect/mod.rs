//! Face detection with SeetaFace's funnel-structured cascade (Wu et al. 2016), through the
//! `rustface` crate, and the box the 68-point landmarker expects.
//!
//! # The model
//!
//! SeetaFace's frontal detection model (`seeta_fd_frontal_v1.0.bin`, 1.2 MB, BSD 2-Clause,
//! `LICENSE-SeetaFace.txt` beside it) ships inside the `rustface` crate's package; it is copied
//! here unchanged (sha256 `c4619d06…61db3ff5d`) and embedded in the library with
//! `include_bytes!`, so detection needs no file and no network. `tools/fetch-models` checks the
//! copy against the crate's.
//!
//! # Boxes
//!
//! dlib's `shape_predictor_68_face_landmarks.dat` was trained on boxes from dlib's own HOG
//! detector, which frame a face differently from SeetaFace's. [`landmark_box`] maps a SeetaFace
//! box to the box dlib's detector would draw, by a scale and shift fitted on dlib's fixture
//! (see its documentation).

use std::sync::OnceLock;

use crate::landmarker::FaceBox;

static MODEL: &[u8] = include_bytes!("seeta_fd_frontal_v1.0.bin");

/// A detected face: SeetaFace's box and score.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// The box, image pixels.
    pub bbox: FaceBox,
    /// The detector's score (higher is surer).
    pub score: f64,
}

impl Detection {
    /// The box's area in pixels.
    pub fn area(&self) -> i64 {
        (self.bbox.right - self.bbox.left + 1) * (self.bbox.bottom - self.bbox.top + 1)
    }
}

fn model() -> &'static rustface::model::Model {
    static PARSED: OnceLock<rustface::model::Model> = OnceLock::new();
    PARSED.get_or_init(|| {
        rustface::read_model(MODEL).expect("the embedded SeetaFace model parses (a test checks it)")
    })
}

/// The smallest side of an image the detector is run on (its window is 40 pixels).
pub const MIN_SIDE: u32 = 40;

/// The longest side detection runs at: a larger photo is searched on a copy scaled down to
/// it, and the boxes scaled back (the landmarks then use the full-resolution photo). Faces in
/// portraits are large; the smallest face found in the original grows by the same factor
/// (from 20 pixels to 20 / scale).
///
/// Chosen, not tuned: at 640 the photo-realistic evaluation's 800 × 1000 photos would be
/// searched at 0.64 scale, which moves the boxes, hence the landmarks, hence which photos
/// pass the landmark agreement (measured on `lps-head`, 8 sets: mean ratio to the mean face
/// 0.871 against 0.888, the two given sets 0.89 / 0.83 against 0.88 / 0.81: a change, not a
/// gain). At 1024 every photo up to 1024 pixels is searched as before (dlib's fixture: 42 of
/// 43 faces, 24 in `bald_guys.jpg`, at 640, 1024 and full size alike) and large photos, where
/// the time goes, are searched at a fraction of the cost.
pub const DETECTION_SIDE: u32 = 1024;

/// Detects faces in a grey image, largest first; faces under the detector's 40-pixel window
/// (at the detection's scale, [`DETECTION_SIDE`]) are not searched for. Images with a side
/// under [`MIN_SIDE`] give no faces.
pub fn detect_faces(image: &image::GrayImage) -> Vec<Detection> {
    detect_faces_within(image, DETECTION_SIDE)
}

/// [`detect_faces`] with the search run on a copy scaled down to `side` pixels along its
/// longest side when the image is larger (`u32::MAX`: always at full size).
pub fn detect_faces_within(image: &image::GrayImage, side: u32) -> Vec<Detection> {
    let (width, height) = image.dimensions();
    if width < MIN_SIDE || height < MIN_SIDE {
        return Vec::new();
    }
    let long = width.max(height);
    if long > side.max(MIN_SIDE) {
        let scale = f64::from(side.max(MIN_SIDE)) / f64::from(long);
        let (w, h) = (
            ((f64::from(width) * scale).round() as u32).max(MIN_SIDE),
            ((f64::from(height) * scale).round() as u32).max(MIN_SIDE),
        );
        let small = triangle_scaled(image, w, h);
        let (sx, sy) = (f64::from(width) / f64::from(w), f64::from(height) / f64::from(h));
        let back = |v: i64, s: f64| (v as f64 * s).round() as i64;
        return search(&small)
            .into_iter()
            .map(|d| Detection {
                bbox: FaceBox {
                    left: back(d.bbox.left, sx),
                    top: back(d.bbox.top, sy),
                    right: back(d.bbox.right + 1, sx) - 1,
                    bottom: back(d.bbox.bottom + 1, sy) - 1,
                },
                ..d
            })
            .collect();
    }
    search(image)
}

/// One axis of [`triangle_scaled`]: for each of `count` pixels of the copy, its first source
/// pixel and the normalised weights from there, as `image`'s triangle filter computes them
/// (the same `f32` operations in the same order).
fn triangle_weights(source: u32, count: u32) -> Vec<(usize, Vec<f32>)> {
    let ratio = source as f32 / count as f32;
    let scale = ratio.max(1.0);
    // The triangle's support, 1, stretched by the scale.
    let support = scale;
    let mut weights = Vec::with_capacity(count as usize);
    for c in 0..count {
        let centre = (c as f32 + 0.5) * ratio;
        let left = ((centre - support).floor() as i64).clamp(0, i64::from(source) - 1);
        let right = ((centre + support).ceil() as i64).clamp(left + 1, i64::from(source));
        let centre = centre - 0.5;
        let mut w: Vec<f32> = (left..right)
            .map(|i| {
                let x = ((i as f32 - centre) / scale).abs();
                if x < 1.0 { 1.0 - x } else { 0.0 }
            })
            .collect();
        let sum: f32 = w.iter().fold(0.0, |s, v| s + v);
        w.iter_mut().for_each(|v| *v /= sum);
        weights.push((left as usize, w));
    }
    weights
}

/// `image` scaled to `width × height` with the triangle filter: the same pixels, bit for bit,
/// as `image::imageops::resize(image, width, height, FilterType::Triangle)` (columns first,
/// into `f32`, then rows, rounded), which works on four channels through generic pixels and
/// took about 4 ms of each 800 × 1000 photo's coarse search; this takes the one channel
/// directly (a test compares the two).
///
/// Measured and dropped: the copy averaged over each pixel's footprint straight from the
/// colour photo (no grey photo at full size) took the photos' stage of `lps-head/photos-8`
/// from 206 to 164 ms best (this filter: 214 → 188, `tools/ab-bench`), but the boxes moved by
/// a few pixels, dlib's points by 2.5–12 and on one photo entirely (its landmarks then passed
/// the agreement test, and the set was reconstructed from 8 photos instead of 7, in more time):
/// the photo-realistic evaluation's 105 sets 0.698 of the mean face against 0.700, 41 better
/// and 51 worse by more than 0.005, `photos-8` 0.88 against 0.83. A change, not a gain, so
/// detection sees the same copy as before.
fn triangle_scaled(image: &image::GrayImage, width: u32, height: u32) -> image::GrayImage {
    let (source_width, source_height) = image.dimensions();
    if (width, height) == (source_width, source_height) {
        return image.clone();
    }
    let down = triangle_weights(source_height, height);
    let across = triangle_weights(source_width, width);
    let (sw, raw) = (source_width as usize, image.as_raw());
    // Down the columns: each row of the copy's height from the source rows it weighs.
    let mut tall = vec![0.0f32; height as usize * sw];
    for (out, (first, weights)) in tall.chunks_exact_mut(sw).zip(&down) {
        for (k, w) in weights.iter().enumerate() {
            let row = &raw[(first + k) * sw..(first + k + 1) * sw];
            for (o, &v) in out.iter_mut().zip(row) {
                *o += f32::from(v) * w;
            }
        }
    }
    // Across the rows.
    let mut copy = Vec::with_capacity(width as usize * height as usize);
    for row in tall.chunks_exact(sw) {
        for (first, weights) in &across {
            let t = weights
                .iter()
                .zip(&row[*first..])
                .fold(0.0f32, |t, (w, v)| t + v * w);
            copy.push(t.clamp(0.0, 255.0).round() as u8);
        }
    }
    image::GrayImage::from_raw(width, height, copy).expect("the copy's size matches its pixels")
}

/// The longest side of the first, coarse search for a photo's subject ([`detect_subject_faces`]).
///
/// Chosen from the search's cost and reach: SeetaFace's work grows with the pixels searched,
/// and its window is [`MIN_SIDE`] pixels at the searched scale, so a copy with a longest side
/// of 400 finds faces of a tenth of the photo's longest side and more. A portrait's face is
/// larger than that (the photo-realistic evaluation's are 22–45% of an 800-pixel width; dlib's
/// fixture portraits about a third); where it is not, the fallback searches at
/// [`DETECTION_SIDE`]. On an 800 × 1000 photo the coarse search costs about a sixth of the full
/// one.
pub const SUBJECT_SEARCH_SIDE: u32 = 400;

/// How much further than needed the coarse search must have reached before its answer stands
/// ([`detect_subject_faces`]): a face the detector only just finds at its smallest window may
/// be missed, so the faces that could make the subject ambiguous must be at least this factor
/// above the window.
pub const SUBJECT_SEARCH_MARGIN: f64 = 1.25;

/// The least score of the largest face in the coarse search for its answer to stand
/// ([`detect_subject_faces`]).
///
/// Chosen from what the coarse search found where the full one did not: on dlib's fixture and
/// the photo-realistic evaluation's 168 rendered photos (7 subjects, yaw up to ±56°) it found
/// two faces the full search rejects, scored 3.1 and 3.3 (one on `dogs.jpg`), while the subjects
/// both searches found scored 2.6–44 in the coarse one (4 of 160 under 5). Below this the photo
/// is searched in full, so those decisions stay the full search's.
pub const SUBJECT_SEARCH_MIN_SCORE: f64 = 5.0;

/// Detects the faces that decide a photo's subject ([`subject_face`]), largest first, by a
/// coarse search first.
///
/// The subject is the largest face, and only faces of at least [`AMBIGUOUS_FACE_AREA`] of its
/// area (`√0.5 ≈ 0.71` of its width) can make it ambiguous. So the photo is first searched on a
/// copy scaled to [`SUBJECT_SEARCH_SIDE`] pixels along its longest side, where the smallest face
/// found is [`MIN_SIDE`] pixels at that scale. When the largest face found there is so large
/// that every face that could rival it is at least [`SUBJECT_SEARCH_MARGIN`] times that
/// smallest size, and the detector is sure of it (a score of at least
/// [`SUBJECT_SEARCH_MIN_SCORE`]), the coarse answer stands; otherwise (no face, a small one or
/// an unsure one) the photo is searched as [`detect_faces`] does. Clearly smaller faces may be missing from the answer
/// (they are ignored by [`subject_face`] anyway, but its note about them is then absent).
pub fn detect_subject_faces(image: &image::GrayImage) -> Vec<Detection> {
    let long = image.width().max(image.height());
    if long <= SUBJECT_SEARCH_SIDE {
        return detect_faces(image);
    }
    let coarse = detect_faces_within(image, SUBJECT_SEARCH_SIDE);
    if coarse.first().is_some_and(|largest| {
        largest.score >= SUBJECT_SEARCH_MIN_SCORE && coarse_search_suffices(largest, long)
    }) {
        return coarse;
    }
    detect_faces(image)
}

/// Whether every face that could rival `largest` (found by the coarse search of an image with
/// longest side `long`) is surely within that search's reach ([`detect_subject_faces`]).
fn coarse_search_suffices(largest: &Detection, long: u32) -> bool {
    let b = largest.bbox;
    let width = ((b.right - b.left + 1).min(b.bottom - b.top + 1)) as f64;
    let smallest_found = f64::from(MIN_SIDE) * f64::from(long) / f64::from(SUBJECT_SEARCH_SIDE);
    AMBIGUOUS_FACE_AREA.sqrt() * width >= SUBJECT_SEARCH_MARGIN * smallest_found
}

/// SeetaFace's search of the whole image, largest face first.
fn search(image: &image::GrayImage) -> Vec<Detection> {
    let (width, height) = image.dimensions();
    let mut detector = rustface::create_detector_with_model(model().clone());
    // rustface 0.1.7 starts its pyramid at the image's own scale whatever this is (its
    // `set_max_scale` call is commented out), so the smallest face found is the 40-pixel window.
    detector.set_min_face_size(20);
    detector.set_score_thresh(2.0);
    detector.set_pyramid_scale_factor(0.8);
    detector.set_slide_window_step(4, 4);
    let data = rustface::ImageData::new(image.as_raw(), width, height);
    let mut faces: Vec<Detection> = detector
        .detect(&data)
        .iter()
        .map(|f| {
            let b = f.bbox();
            Detection {
                bbox: FaceBox::from_size(
                    i64::from(b.x()),
                    i64::from(b.y()),
                    i64::from(b.width()),
                    i64::from(b.height()),
                ),
                score: f.score(),
            }
        })
        .collect();
    faces.sort_by_key(|d| std::cmp::Reverse(d.area()));
    faces
}

/// How a SeetaFace box maps to dlib's: left/top shifted by these fractions of its width/height,
/// width/height scaled by these factors (see [`landmark_box`]).
///
/// Fitted (mean ratios) on the 42 faces of dlib's fixture (`../shared/data/dlib-faces`) that
/// SeetaFace finds (of 43), pairing each with dlib's box by overlap: dlib's boxes sit 9.4% of the
/// height lower and are 3.4% smaller. With them, the 68 points found from SeetaFace's boxes are
/// 3.49% of the box width from the points dlib finds from its own boxes, against 3.80% with the
/// raw boxes (in-sample; the ignored test `detection_and_landmarks_on_the_fixture` measures it).
pub const BOX_CALIBRATION: [f64; 4] = [0.0008, 0.094, 0.966, 0.967];

/// The box dlib's detector would draw around the face SeetaFace found (see the module
/// documentation).
pub fn landmark_box(detection: &Detection) -> FaceBox {
    let b = detection.bbox;
    let (w, h) = ((b.right - b.left + 1) as f64, (b.bottom - b.top + 1) as f64);
    let [dx, dy, sx, sy] = BOX_CALIBRATION;
    let left = (b.left as f64 + dx * w).round() as i64;
    let top = (b.top as f64 + dy * h).round() as i64;
    FaceBox::from_size(
        left,
        top,
        (sx * w).round().max(1.0) as i64,
        (sy * h).round().max(1.0) as i64,
    )
}

/// A second face at least this fraction of the largest face's area makes a photo ambiguous
/// (see [`subject_face`]).
///
/// Chosen, not fitted: a photo of the subject may hold a small face in the background (a
/// poster, a passer-by), which is safely ignored, but two faces of about one size leave no way
/// to tell which is the subject's. Half the area is about 0.71 of the width. The dlib fixture's
/// group photos (`bald_guys.jpg`, `2008_002470.jpg`: several people side by side) fall on the
/// ambiguous side.
pub const AMBIGUOUS_FACE_AREA: f64 = 0.5;

/// Why a photo gives no subject landmarks: its detections give no subject face, or the model
/// cannot landmark it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SubjectProblem {
    /// The landmark model does not give iBUG's 68 points.
    #[error("the landmark model gives {points} points, not the 68 of iBUG")]
    WrongModel {
        /// The model's points.
        points: usize,
    },
    /// The model gave no usable points from any starting box.
    #[error("the landmark model gave no usable points")]
    NoPoints,
    /// The landmarks cannot be used (not finite).
    #[error("its landmarks: {error}")]
    Points {
        /// Why.
        error: crate::align::AlignError,
    },
    /// Nothing was detected.
    #[error("no face found")]
    NoFace,
    /// Two or more faces of about one size.
    #[error(
        "{count} faces found and the two largest are of about one size ({first} and {second} px² boxes), \
         so which is the subject's is ambiguous"
    )]
    Ambiguous {
        /// How many faces were found.
        count: usize,
        /// The largest box's area, pixels.
        first: i64,
        /// The second largest box's area, pixels.
        second: i64,
    },
}

/// The subject's face among a photo's detections (as [`detect_faces`] orders them, largest
/// first), and a note when other, clearly smaller faces were ignored.
///
/// # Errors
/// [`SubjectProblem::NoFace`] without detections; [`SubjectProblem::Ambiguous`] when the
/// second largest face has at least [`AMBIGUOUS_FACE_AREA`] of the largest one's area.
pub fn subject_face(faces: &[Detection]) -> Result<(Detection, Option<String>), SubjectProblem> {
    let mut by_size = faces.to_vec();
    by_size.sort_by_key(|d| std::cmp::Reverse(d.area()));
    let Some(&largest) = by_size.first() else {
        return Err(SubjectProblem::NoFace);
    };
    let Some(second) = by_size.get(1) else {
        return Ok((largest, None));
    };
    if second.area() as f64 >= AMBIGUOUS_FACE_AREA * largest.area() as f64 {
        return Err(SubjectProblem::Ambiguous {
            count: by_size.len(),
            first: largest.area(),
            second: second.area(),
        });
    }
    let note = format!(
        "{} faces found; the largest is used ({:.1}× the next one's area)",
        by_size.len(),
        largest.area() as f64 / second.area() as f64
    );
    Ok((largest, Some(note)))
}

/// A photo's subject face, found and landmarked by [`landmark_subject`].
#[derive(Debug, Clone, PartialEq)]
pub struct LandmarkedFace {
    /// The detection used.
    pub face: Detection,
    /// The 68 iBUG points, image pixels (`y` down).
    pub ibug: Vec<nalgebra::Point2<crate::Real>>,
    /// How far the model's answer on the mirrored photo lies from its answer on the photo:
    /// the mean distance over the 51 points off the jaw, as a fraction of the distance
    /// between the outer eye corners. A face the model is sure of gives a few percent.
    pub disagreement: crate::Real,
    /// A note when other, clearly smaller faces were ignored.
    pub note: Option<String>,
}

/// The horizontal shifts of the starting box tried by [`landmark_face`], as fractions of the
/// box's width.
///
/// On a face turned by more than about 35° SeetaFace's box frames the head rather than the
/// face, and from such a box dlib's model often converges to a face turned the other way
/// (the points of `lps-head/photos-8/img04.png`, yaw +37°, came out with a fitted yaw of
/// −0.1°). Measured on 74 rendered photos of 3 subjects (yaw ±56°; `tools/photo_eval`): the
/// SeetaFace box alone gave 7 photos with their points off by more than 20% of the eye
/// distance (mean error, capped at 30%, 8.4%); these three shifts, each started from the photo
/// and from its mirror image and the answer chosen by mirror agreement, gave 0–1 (5.1–5.3%).
/// The centre start alone, with the mirror, left 3 (6.1%).
pub const BOX_SHIFTS: [crate::Real; 3] = [-0.2, 0.0, 0.2];

fn mirrored_points(
    points: &[nalgebra::Point2<crate::Real>],
    width: u32,
) -> Vec<nalgebra::Point2<crate::Real>> {
    crate::structure::IBUG_MIRROR
        .iter()
        .map(|&k| nalgebra::Point2::new(crate::Real::from(width) - 1.0 - points[k].x, points[k].y))
        .collect()
}

fn mirrored_box(b: FaceBox, width: u32) -> FaceBox {
    let w = i64::from(width);
    FaceBox {
        left: w - 1 - b.right,
        right: w - 1 - b.left,
        ..b
    }
}

/// Landmarks a detected face with a 68-point model, robustly: starting boxes shifted by
/// [`BOX_SHIFTS`], each run on the photo and on its mirror image; each answer is checked
/// against the model's answer on the other image from the box that answer implies
/// ([`crate::landmarker::ShapePredictor::box_for`]), and the pair that agrees best is
/// averaged (the mirror cancels much of the model's lean on turned faces). The agreement is
/// returned as [`LandmarkedFace::disagreement`].
///
/// # Errors
/// [`SubjectProblem::WrongModel`] when the model does not give 68 points.
pub fn landmark_face(
    model: &crate::landmarker::ShapePredictor,
    image: &image::RgbImage,
    face: Detection,
) -> Result<LandmarkedFace, SubjectProblem> {
    use crate::landmarker::Intensity;
    if model.points() != crate::structure::IBUG_POINT_COUNT {
        return Err(SubjectProblem::WrongModel {
            points: model.points(),
        });
    }
    let width = image.width();
    let photo = Intensity::from_rgb(image);
    let mirror = photo.mirrored();
    let sides = [photo, mirror];
    let start = landmark_box(&face);
    let box_width = (start.right - start.left) as crate::Real;
    // The answer on side `s`, in the photo's frame.
    let on_side = |points: Vec<nalgebra::Point2<crate::Real>>, s: usize| {
        if s == 0 {
            points
        } else {
            mirrored_points(&points, width)
        }
    };
    let on_image = |b: FaceBox, s: usize| if s == 0 { b } else { mirrored_box(b, width) };
    // Every start: each shift, on the photo and on its mirror image, with the other side to
    // check it on. The model runs each round's faces together (`predict_all`).
    let starts: Vec<(usize, usize, FaceBox)> = BOX_SHIFTS
        .iter()
        .flat_map(|shift| {
            let dx = (shift * box_width).round() as i64;
            let shifted = FaceBox {
                left: start.left + dx,
                right: start.right + dx,
                ..start
            };
            [(0, 1), (1, 0)].map(|(side, other)| (side, other, on_image(shifted, side)))
        })
        .collect();
    let answers: Vec<_> = model
        .predict_all(
            &starts
                .iter()
                .map(|&(side, _, b)| (&sides[side], b))
                .collect::<Vec<_>>(),
        )
        .into_iter()
        .zip(&starts)
        .map(|(points, &(side, _, _))| on_side(points, side))
        .collect();
    // The other side's answer from the box each answer implies (where it implies one).
    let checked: Vec<(usize, FaceBox)> = answers
        .iter()
        .zip(&starts)
        .enumerate()
        .filter_map(|(i, (answer, &(_, other, _)))| model.box_for(answer).map(|b| (i, on_image(b, other))))
        .collect();
    let checks = model.predict_all(
        &checked
            .iter()
            .map(|&(i, b)| (&sides[starts[i].1], b))
            .collect::<Vec<_>>(),
    );
    let mut best: Option<(crate::Real, Vec<nalgebra::Point2<crate::Real>>)> = None;
    for (&(i, _), check) in checked.iter().zip(checks) {
        let answer = &answers[i];
        let check = on_side(check, starts[i].1);
        let eyes = (answer[45] - answer[36]).norm().max(1.0);
        let disagreement = (17..68)
            .map(|k| (answer[k] - check[k]).norm())
            .sum::<crate::Real>()
            / 51.0
            / eyes;
        if best.as_ref().is_none_or(|(d, _)| disagreement < *d) {
            let mean = answer
                .iter()
                .zip(&check)
                .map(|(a, b)| nalgebra::center(a, b))
                .collect();
            best = Some((disagreement, mean));
        }
    }
    let (disagreement, ibug) = best.ok_or(SubjectProblem::NoPoints)?;
    Ok(LandmarkedFace {
        face,
        ibug,
        disagreement,
        note: None,
    })
}

/// Detects the faces in a photo and landmarks the subject's ([`detect_subject_faces`],
/// [`subject_face`], [`landmark_face`]).
///
/// # Errors
/// A [`SubjectProblem`] when no subject face is found or the model does not give 68 points.
pub fn landmark_subject(
    model: &crate::landmarker::ShapePredictor,
    image: &image::DynamicImage,
) -> Result<LandmarkedFace, SubjectProblem> {
    landmark_subject_timed(model, image).map(|(found, _)| found)
}

/// [`landmark_subject`], with the seconds its detection and its landmarks took.
///
/// # Errors
/// As [`landmark_subject`].
pub(crate) fn landmark_subject_timed(
    model: &crate::landmarker::ShapePredictor,
    image: &image::DynamicImage,
) -> Result<(LandmarkedFace, [f64; 2]), SubjectProblem> {
    let start = std::time::Instant::now();
    let (face, note) = subject_face(&detect_subject_faces(&image.to_luma8()))?;
    let detection = start.elapsed().as_secs_f64();
    let start = std::time::Instant::now();
    // An 8-bit RGB photo as it is; any other form converted.
    let rgb = match image.as_rgb8() {
        Some(rgb) => std::borrow::Cow::Borrowed(rgb),
        None => std::borrow::Cow::Owned(image.to_rgb8()),
    };
    let found = landmark_face(model, &rgb, face)?;
    Ok((
        LandmarkedFace { note, ..found },
        [detection, start.elapsed().as_secs_f64()],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(side: i64) -> Detection {
        Detection {
            bbox: FaceBox::from_size(0, 0, side, side),
            score: 5.0,
        }
    }

    /// The coarse search's answer stands exactly when a rival of half the largest face's area
    /// is at least the margin above the smallest face the coarse search finds.
    #[test]
    fn the_coarse_search_suffices_above_its_reach() {
        // An image of longest side 1000 searched at 400: the smallest face found is 100 px, so
        // rivals need 125 px, and the largest face 125 / √0.5 = 176.8 px.
        let long = 1000;
        let needed = SUBJECT_SEARCH_MARGIN * f64::from(MIN_SIDE) * f64::from(long)
            / f64::from(SUBJECT_SEARCH_SIDE)
            / AMBIGUOUS_FACE_AREA.sqrt();
        assert!((needed - 176.78).abs() < 0.01, "{needed}");
        assert!(!coarse_search_suffices(&square(176), long));
        assert!(coarse_search_suffices(&square(177), long));
        // A box as tall as needed but too narrow does not suffice.
        let narrow = Detection {
            bbox: FaceBox::from_size(0, 0, 100, 300),
            score: 5.0,
        };
        assert!(!coarse_search_suffices(&narrow, long));
        // Twice the photo, twice the face needed.
        assert!(!coarse_search_suffices(&square(300), 2 * long));
        assert!(coarse_search_suffices(&square(354), 2 * long));
    }

    /// Images no larger than the coarse search are searched once, as `detect_faces` does.
    #[test]
    fn small_images_are_searched_as_a_whole() {
        let image = image::GrayImage::from_fn(300, 200, |x, y| image::Luma([((x * 7 + y * 3) % 256) as u8]));
        assert_eq!(detect_subject_faces(&image), detect_faces(&image));
    }

    /// The triangle-filtered copy is `image`'s resize to the bit, shrinking and growing, on
    /// noise and on edges (its own implementation is the oracle).
    #[test]
    fn triangle_scaling_is_images_resize() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 24) as u8
        };
        for (w, h, to_w, to_h) in [
            (800, 1000, 320, 400),
            (97, 61, 40, 41),
            (333, 500, 333, 200),
            (50, 40, 80, 45),
        ] {
            let noise = image::GrayImage::from_fn(w, h, |_, _| image::Luma([next()]));
            let edges = image::GrayImage::from_fn(w, h, |x, y| {
                image::Luma([if (x / 7 + y / 5) % 2 == 0 { 250 } else { 3 }])
            });
            for image in [noise, edges] {
                let expected =
                    image::imageops::resize(&image, to_w, to_h, image::imageops::FilterType::Triangle);
                assert_eq!(
                    triangle_scaled(&image, to_w, to_h),
                    expected,
                    "{w} × {h} → {to_w} × {to_h}"
                );
            }
        }
    }
}
