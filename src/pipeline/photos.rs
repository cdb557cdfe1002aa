//! Photos and landmark files gathered into [`Input`]s, and each photo's own outputs.
//!
//! [`gather_inputs`] is what `splineface reconstruct`, `splineface batch` and the Python
//! package's `reconstruct` share: a list of photos (decoded, detected and landmarked in
//! parallel, or matched by name to landmark files) or a folder of landmark files alone. A photo
//! that cannot be used is skipped with its reason rather than stopping the run;
//! [`PhotoSet::check_count`] then says whether enough are left. [`PhotoSet::files`] adds what
//! the photos themselves give to a reconstruction's files: each photo's overlay, the detected
//! landmarks, the skipped photos and the photo stages' times in `report.json`, and `report.html`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Point2;
use rayon::prelude::*;

use super::{Input, PhotoImage, PipelineError, PipelineOptions, Reconstruction};
use crate::Real;
use crate::align::PhotoPoints;
use crate::detect::LandmarkedFace;
use crate::landmarker::ShapePredictor;
use crate::landmarks::{LandmarkPoints, read_landmarks_json, read_pts};
use crate::reference::ReferenceFace;
use crate::structure::from_ibug68;

/// The photo file extensions a folder of photos is read for (case-insensitive).
pub const IMAGE_EXTENSIONS: [&str; 7] = ["jpg", "jpeg", "png", "bmp", "tif", "tiff", "webp"];

/// The landmark file extensions: `.pts` (68 iBUG or 40 structure points) and JSON
/// ([`crate::landmarks::parse_landmarks_json`]).
pub const LANDMARK_EXTENSIONS: [&str; 2] = ["pts", "json"];

/// Why the inputs of a reconstruction could not be gathered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    /// A named photo does not exist.
    #[error("{}: no such file", path.display())]
    NoSuchFile {
        /// The photo.
        path: PathBuf,
    },
    /// A folder could not be listed.
    #[error("cannot read the directory {}: {error}", path.display())]
    Directory {
        /// The folder.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// Neither photos nor a landmark folder were given.
    #[error("nothing to reconstruct from: give photos and/or a folder of landmark files")]
    Nothing,
    /// A landmark folder without photos holds no landmark files.
    #[error("{}: no landmark files (.pts or .json)", path.display())]
    NoLandmarkFiles {
        /// The folder.
        path: PathBuf,
    },
    /// Photos were given with neither landmark files nor a landmark model.
    #[error("the photos need landmarks: give a folder of landmark files or a landmark model")]
    NoLandmarks,
    /// A landmark file could not be used.
    #[error("{}: {message}", path.display())]
    LandmarkFile {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// No usable photo has the name asked for.
    #[error("no usable photo has that name (the photos are {})", photos.join(", "))]
    NoSuchPhoto {
        /// The name asked for.
        name: String,
        /// The usable photos' names.
        photos: Vec<String>,
    },
    /// Fewer usable photos than the reconstruction needs.
    #[error(
        "{usable} usable photo{}, at least {needed} needed{}",
        if *usable == 1 { "" } else { "s" },
        skipped.iter().map(|s| format!("\n  skipped {s}")).collect::<String>()
    )]
    TooFewPhotos {
        /// How many were usable.
        usable: usize,
        /// How many are needed.
        needed: usize,
        /// Each skipped photo, `path: reason`.
        skipped: Vec<String>,
    },
    /// No photo given to [`landmark_photos`] gave landmarks.
    #[error("no photo gave landmarks:{}", lines.iter().map(|l| format!("\n  {l}")).collect::<String>())]
    NoneLandmarked {
        /// What became of each photo.
        lines: Vec<String>,
    },
}

/// The files of `dir` with one of `extensions` (case-insensitive), sorted by name.
///
/// # Errors
/// [`InputError::Directory`] if `dir` cannot be listed.
pub(crate) fn files_in(dir: &Path, extensions: &[&str]) -> Result<Vec<PathBuf>, InputError> {
    let entries = std::fs::read_dir(dir).map_err(|error| InputError::Directory {
        path: dir.to_path_buf(),
        error,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && has_extension(p, extensions))
        .collect();
    files.sort();
    Ok(files)
}

/// Whether `path`'s extension is one of `extensions` (case-insensitive).
pub(crate) fn has_extension(path: &Path, extensions: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// `photos` followed by the photos of `folder` ([`IMAGE_EXTENSIONS`], sorted by name).
///
/// # Errors
/// [`InputError::Directory`] if the folder cannot be listed, [`InputError::NoSuchFile`] for a
/// photo that does not exist.
pub fn photo_list(photos: &[PathBuf], folder: Option<&Path>) -> Result<Vec<PathBuf>, InputError> {
    let mut paths = photos.to_vec();
    if let Some(dir) = folder {
        paths.extend(files_in(dir, &IMAGE_EXTENSIONS)?);
    }
    if let Some(missing) = paths.iter().find(|p| !p.exists()) {
        return Err(InputError::NoSuchFile {
            path: missing.clone(),
        });
    }
    Ok(paths)
}

/// A photo's name in every output: its file stem.
pub(crate) fn photo_stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// The landmark file for a photo stem in `dir`: `STEM.pts` or `STEM.json`.
pub(crate) fn landmark_file(dir: &Path, stem: &str) -> Option<PathBuf> {
    LANDMARK_EXTENSIONS
        .iter()
        .map(|e| dir.join(format!("{stem}.{e}")))
        .find(|p| p.is_file())
}

/// A photo's 40 points from a landmark file (`.pts` with 68 iBUG or 40 structure points, or
/// JSON; with 68 also its inner lips), named by the file's stem, and the file's own points as read (68 or 40, for the
/// photo's overlay).
///
/// # Errors
/// [`InputError::LandmarkFile`] naming the file and the problem.
pub(crate) fn read_photo_points(path: &Path) -> Result<(PhotoPoints, Vec<Point2<Real>>), InputError> {
    let problem = |message: String| InputError::LandmarkFile {
        path: path.to_path_buf(),
        message,
    };
    let named = |e: crate::landmarks::LandmarkError| problem(e.problem.to_string());
    let (points, raw) = if has_extension(path, &["json"]) {
        let landmarks = read_landmarks_json(path).map_err(named)?;
        let points = landmarks
            .structure_2d()
            .map_err(|e| problem(format!("2D landmarks are needed: {e}")))?;
        let raw = match landmarks.points {
            LandmarkPoints::Planar(raw) => raw,
            LandmarkPoints::Spatial(_) => points.clone(),
        };
        (points, raw)
    } else {
        let raw = read_pts(path).map_err(named)?;
        let points = match raw.len() {
            68 => from_ibug68(&raw).map_err(|e| problem(e.to_string()))?,
            40 => raw.clone(),
            n => {
                return Err(problem(format!(
                    "{n} points; expected 68 (iBUG) or 40 (the structure)"
                )));
            }
        };
        (points, raw)
    };
    // 68 iBUG points also give the inner lips.
    let points = if raw.len() == crate::structure::IBUG_POINT_COUNT {
        PhotoPoints::from_ibug68(photo_stem(path), &raw)
    } else {
        PhotoPoints::new(photo_stem(path), points)
    }
    .map_err(|e| problem(e.to_string()))?;
    Ok((points, raw))
}

/// Detects the faces in a photo and landmarks the subject's
/// ([`crate::detect::landmark_subject_timed`]): its 40 points named `name`, the detector's
/// answer (box, 68 points, a note when smaller faces were ignored), and the seconds the
/// detection and the landmarks took.
///
/// # Errors
/// Why no subject was landmarked ([`crate::detect::SubjectProblem`]).
pub(crate) fn landmark_photo(
    model: &ShapePredictor,
    image: &image::DynamicImage,
    name: &str,
) -> Result<(PhotoPoints, LandmarkedFace, [f64; 2]), crate::detect::SubjectProblem> {
    let (found, seconds) = crate::detect::landmark_subject_timed(model, image)?;
    let points = PhotoPoints::from_ibug68(name, &found.ibug)
        .map_err(|error| crate::detect::SubjectProblem::Points { error })?;
    Ok((points, found, seconds))
}

/// The index among `inputs` of the photo named `name` (for
/// [`super::PipelineOptions::expression_of`]).
///
/// # Errors
/// [`InputError::NoSuchPhoto`], listing the usable photos' names.
pub fn photo_index(inputs: &[Input], name: &str) -> Result<usize, InputError> {
    inputs
        .iter()
        .position(|i| i.points.name == name)
        .ok_or_else(|| InputError::NoSuchPhoto {
            name: name.to_owned(),
            photos: inputs.iter().map(|i| i.points.name.clone()).collect(),
        })
}

/// One photo as read and landmarked: what its overlay and landmark file are made of.
#[derive(Debug, Clone)]
pub struct PhotoRecord {
    /// Its name (the file stem).
    pub name: String,
    /// The photo, when the record keeps it (a reconstructed photo's is in its [`Input`]).
    pub image: Option<image::RgbImage>,
    /// The detector's box `[x, y, width, height]`, when detected.
    pub face_box: Option<[f64; 4]>,
    /// The landmarks as detected (68) or read from its file (68 or 40), pixels.
    pub landmarks: Vec<Point2<Real>>,
    /// Whether the landmarks were detected (not read from a file).
    pub detected: bool,
    /// Why the photo was skipped, if it was.
    pub skipped: Option<String>,
}

impl PhotoRecord {
    /// A photo whose landmarks were given (a landmark file, the demo's points), not detected.
    pub fn given(name: &str, landmarks: Vec<Point2<Real>>) -> Self {
        PhotoRecord {
            name: name.to_owned(),
            image: None,
            face_box: None,
            landmarks,
            detected: false,
            skipped: None,
        }
    }

    /// A photo skipped for `reason`, with its picture when it could be decoded.
    pub fn skipped(name: &str, image: Option<image::RgbImage>, reason: String) -> Self {
        PhotoRecord {
            name: name.to_owned(),
            image,
            face_box: None,
            landmarks: Vec::new(),
            detected: false,
            skipped: Some(reason),
        }
    }

    /// A photo whose subject the detector found and landmarked.
    pub fn from_detection(name: &str, found: &LandmarkedFace) -> Self {
        let b = found.face.bbox;
        PhotoRecord {
            name: name.to_owned(),
            image: None,
            face_box: Some([
                b.left as f64,
                b.top as f64,
                (b.right - b.left + 1) as f64,
                (b.bottom - b.top + 1) as f64,
            ]),
            landmarks: found.ibug.clone(),
            detected: true,
            skipped: None,
        }
    }
}

/// How long one photo's stages took, seconds.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoTiming {
    /// The photo's name.
    pub name: String,
    /// Decoding.
    pub decoding: f64,
    /// Face detection (0 with a landmark file).
    pub detection: f64,
    /// Landmarks (0 with a landmark file).
    pub landmarks: f64,
}

/// What [`gather_inputs`] made of the photos and landmark files.
#[derive(Debug, Clone, Default)]
pub struct PhotoSet {
    /// The usable photos (or points), in the order given.
    pub inputs: Vec<Input>,
    /// Every photo read, used or skipped, for the overlays and landmark files
    /// ([`PhotoSet::files`]); empty for a points-only run.
    pub records: Vec<PhotoRecord>,
    /// Each skipped photo or landmark file, `path: reason`.
    pub skipped: Vec<String>,
    /// Detection notes, `path: note`.
    pub warnings: Vec<String>,
    /// The wall time of decoding, detection and landmarks over all photos (in parallel),
    /// seconds; `None` for a points-only run.
    pub seconds: Option<f64>,
    /// Each photo's stage times.
    pub timings: Vec<PhotoTiming>,
    /// Whether any photo's landmarks were to be detected (a model was given).
    pub detecting: bool,
}

/// Gathers a reconstruction's inputs: `photos` (in order, the first of each file stem; their
/// points from `STEM.pts` or `STEM.json` in `landmarks`, else by detection with `model`),
/// decoded and landmarked in parallel; or, without photos, every landmark file in `landmarks`
/// (a points-only run). A photo or landmark file that cannot be used is skipped with its
/// reason ([`PhotoSet::skipped`]); the caller decides with [`PhotoSet::check_count`] whether
/// enough are left.
///
/// # Errors
/// [`InputError::Nothing`] with neither photos nor landmarks, [`InputError::NoLandmarks`] for
/// photos with neither, [`InputError::NoLandmarkFiles`] for an empty landmark folder and
/// [`InputError::Directory`] for one that cannot be read.
pub fn gather_inputs(
    photos: &[PathBuf],
    landmarks: Option<&Path>,
    model: Option<&ShapePredictor>,
) -> Result<PhotoSet, InputError> {
    if photos.is_empty() {
        let dir = landmarks.ok_or(InputError::Nothing)?;
        return gather_landmark_files(dir);
    }
    if landmarks.is_none() && model.is_none() {
        return Err(InputError::NoLandmarks);
    }
    let mut set = PhotoSet {
        detecting: model.is_some(),
        ..PhotoSet::default()
    };
    // Photos are known by their stems (landmark files are matched by them, and the report
    // names them): a second photo with a stem already taken is skipped.
    let mut stems: BTreeMap<String, &Path> = BTreeMap::new();
    let mut unique: Vec<(&Path, String)> = Vec::new();
    for path in photos {
        let stem = photo_stem(path);
        if let Some(first) = stems.get(&stem) {
            set.skipped.push(format!(
                "{}: {} has the same name `{stem}` (photos are matched to landmark files by name)",
                path.display(),
                first.display()
            ));
            continue;
        }
        stems.insert(stem.clone(), path);
        unique.push((path, stem));
    }
    // Decoded, detected and landmarked in parallel; gathered in the photos' order.
    let start = Instant::now();
    let prepared: Vec<Prepared> = unique
        .par_iter()
        .map(|(path, stem)| prepare_photo(path, stem, landmarks, model))
        .collect();
    set.seconds = Some(start.elapsed().as_secs_f64());
    for p in prepared {
        set.warnings.extend(p.warning);
        set.skipped.extend(p.skipped);
        set.inputs.extend(p.input);
        let [decoding, detection, landmarks] = p.seconds;
        set.timings.push(PhotoTiming {
            name: p.record.name.clone(),
            decoding,
            detection,
            landmarks,
        });
        set.records.push(p.record);
    }
    Ok(set)
}

/// Every landmark file of `dir` as a points-only input (the first of each name).
fn gather_landmark_files(dir: &Path) -> Result<PhotoSet, InputError> {
    let files = files_in(dir, &LANDMARK_EXTENSIONS)?;
    if files.is_empty() {
        return Err(InputError::NoLandmarkFiles {
            path: dir.to_path_buf(),
        });
    }
    let mut set = PhotoSet::default();
    for file in files {
        match read_photo_points(&file) {
            Ok((points, _)) => {
                if set.inputs.iter().any(|i| i.points.name == points.name) {
                    set.skipped.push(format!(
                        "{}: another landmark file has the name `{}` (STEM.pts and STEM.json?)",
                        file.display(),
                        points.name
                    ));
                } else {
                    set.inputs.push(Input { points, image: None });
                }
            }
            Err(e) => set.skipped.push(e.to_string()),
        }
    }
    Ok(set)
}

/// One photo made ready for the reconstruction ([`prepare_photo`]).
struct Prepared {
    record: PhotoRecord,
    /// The photo and its points, unless it was skipped.
    input: Option<Input>,
    /// Why it was skipped (`path: reason`).
    skipped: Option<String>,
    /// A detection note (`path: note`).
    warning: Option<String>,
    /// Seconds of decoding, detection and landmarks.
    seconds: [f64; 3],
}

/// Decodes a photo and finds its points: from its landmark file in `landmark_dir`, else by
/// detection and `model`.
fn prepare_photo(
    path: &Path,
    stem: &str,
    landmark_dir: Option<&Path>,
    model: Option<&ShapePredictor>,
) -> Prepared {
    let start = Instant::now();
    let decoded = match crate::align::decode_photo(path) {
        Ok(d) => d,
        Err(e) => {
            return Prepared {
                record: PhotoRecord::skipped(stem, None, e.problem.to_string()),
                input: None,
                skipped: Some(e.to_string()),
                warning: None,
                seconds: [start.elapsed().as_secs_f64(), 0.0, 0.0],
            };
        }
    };
    let mut seconds = [start.elapsed().as_secs_f64(), 0.0, 0.0];
    let skip = |reason: String, seconds: [f64; 3]| Prepared {
        skipped: Some(format!("{}: {reason}", path.display())),
        record: PhotoRecord::skipped(stem, Some(decoded.to_rgb8()), reason),
        input: None,
        warning: None,
        seconds,
    };
    let file = landmark_dir.and_then(|dir| landmark_file(dir, stem));
    let mut warning = None;
    let (points, record) = match (file, model) {
        (Some(file), _) => match read_photo_points(&file) {
            Ok((points, raw)) => (points, PhotoRecord::given(stem, raw)),
            Err(e) => return skip(format!("its landmarks: {e}"), seconds),
        },
        (None, Some(model)) => match landmark_photo(model, &decoded, stem) {
            Ok((points, found, [detection, landmarks])) => {
                seconds[1] = detection;
                seconds[2] = landmarks;
                if let Some(note) = &found.note {
                    warning = Some(format!("{}: {note}", path.display()));
                }
                (points, PhotoRecord::from_detection(stem, &found))
            }
            Err(reason) => return skip(reason.to_string(), seconds),
        },
        (None, None) => {
            return skip(
                format!(
                    "no landmark file {stem}.pts or {stem}.json in {} (and no landmark model)",
                    landmark_dir.map_or_else(String::new, |d| d.display().to_string())
                ),
                seconds,
            );
        }
    };
    // The grey form first, so that the decoded image can become the colour one (no copy).
    match crate::align::GreyImage::from_dynamic(&decoded) {
        Ok(grey) => Prepared {
            record,
            input: Some(Input {
                points: PhotoPoints {
                    name: stem.to_owned(),
                    ..points
                },
                image: Some(PhotoImage {
                    grey,
                    colour: decoded.into_rgb8(),
                }),
            }),
            skipped: None,
            warning,
            seconds,
        },
        Err(e) => Prepared {
            warning,
            ..skip(e.to_string(), seconds)
        },
    }
}

impl PhotoSet {
    /// Whether at least `needed` inputs are usable.
    ///
    /// # Errors
    /// [`InputError::TooFewPhotos`], listing every skipped photo.
    pub fn check_count(&self, needed: usize) -> Result<(), InputError> {
        if self.inputs.len() >= needed {
            return Ok(());
        }
        Err(InputError::TooFewPhotos {
            usable: self.inputs.len(),
            needed,
            skipped: self.skipped.clone(),
        })
    }

    /// Every file of a reconstruction of these photos: `result`'s own
    /// ([`Reconstruction::files`]), each photo's overlay and detected landmarks
    /// (drawn by the pipeline), `report.json` with the skipped photos, detection notes and the photo
    /// stages' times added (`model_seconds`: the landmark model's load, when it was loaded),
    /// and `report.html`. Warnings about outputs that could not be drawn join the report.
    ///
    /// # Errors
    /// As [`Reconstruction::files`]; [`PipelineError::Encode`] if `report.json` cannot be
    /// re-encoded.
    pub fn files(
        &self,
        result: &Reconstruction,
        model_seconds: Option<f64>,
    ) -> Result<Vec<(PathBuf, Vec<u8>)>, PipelineError> {
        let photo_outputs = self.photo_outputs(result);
        self.finish_files(result.files()?, photo_outputs, "overlays", model_seconds)
    }

    /// [`super::reconstruct_files`] on the set's inputs, then [`PhotoSet::files`]: the same
    /// reconstruction and files, sooner. The overlays are drawn while the texture is baked
    /// (they need only the photos' fits), and the report times them there.
    ///
    /// # Errors
    /// As [`super::reconstruct_files`]; [`PipelineError::Encode`] if `report.json` cannot be
    /// re-encoded.
    pub fn reconstruct_files(
        &self,
        reference: &ReferenceFace,
        options: &PipelineOptions,
        progress: impl FnMut(&str),
        model_seconds: Option<f64>,
    ) -> Result<(Reconstruction, super::OutputFiles), PipelineError> {
        let (result, files, overlays) =
            super::reconstruct_files_beside(&self.inputs, reference, options, progress, |result| {
                self.photo_outputs(result)
            })?;
        let files = self.finish_files(
            files,
            overlays,
            "overlays (drawn beside the texture)",
            model_seconds,
        )?;
        Ok((result, files))
    }

    /// The overlays and landmark files ([`photo_files`]), the warnings about them, and the
    /// seconds they took.
    fn photo_outputs(&self, result: &Reconstruction) -> PhotoOutputs {
        let start = Instant::now();
        let mut warnings = Vec::new();
        let files = photo_files(
            &self.records,
            Path::new("landmarks"),
            &self.inputs,
            Some(result),
            &mut warnings,
        );
        PhotoOutputs {
            files,
            warnings,
            seconds: start.elapsed().as_secs_f64(),
        }
    }

    /// A reconstruction's own `files` with the photos' outputs added, `report.json` completed (the
    /// front stages, the overlays' time under `overlay_stage`, the warnings) and the page.
    fn finish_files(
        &self,
        mut files: super::OutputFiles,
        photo_outputs: PhotoOutputs,
        overlay_stage: &str,
        model_seconds: Option<f64>,
    ) -> Result<super::OutputFiles, PipelineError> {
        let mut warnings = self.warnings.clone();
        warnings.extend(photo_outputs.warnings);
        let overlay_seconds = photo_outputs.seconds;
        let photo_outputs = photo_outputs.files;
        let mut front_stages: Vec<serde_json::Value> = Vec::new();
        if let Some(seconds) = model_seconds {
            front_stages.push(serde_json::json!({ "stage": "landmark model", "ms": 1e3 * seconds }));
        }
        if let Some(seconds) = self.seconds {
            front_stages.push(serde_json::json!({
                "stage": "photos: decoding, detection, landmarks (in parallel)",
                "ms": 1e3 * seconds,
            }));
        }
        edit_report(&mut files, |report| {
            if !self.skipped.is_empty() {
                report["photos_skipped"] = self.skipped.clone().into();
            }
            if let Some(list) = report["warnings"].as_array_mut() {
                list.extend(warnings.iter().map(|w| serde_json::Value::from(w.as_str())));
            }
            if let Some(list) = report["timings"].as_array_mut() {
                list.splice(0..0, front_stages);
                list.push(serde_json::json!({ "stage": overlay_stage, "ms": 1e3 * overlay_seconds }));
            }
            if !self.timings.is_empty() {
                report["photo_timings"] = self
                    .timings
                    .iter()
                    .map(|t| {
                        serde_json::json!({
                            "name": t.name,
                            "decoding_ms": 1e3 * t.decoding,
                            "detection_ms": 1e3 * t.detection,
                            "landmarks_ms": 1e3 * t.landmarks,
                        })
                    })
                    .collect::<Vec<_>>()
                    .into();
            }
        })?;
        files.extend(photo_outputs);
        let page_start = Instant::now();
        let page = crate::report::report_page(
            &files,
            &crate::report::PageOptions {
                // From the inputs only, so that the same inputs give the same page wherever it goes.
                title: format!(
                    "splineface: a face from {} photo{}",
                    self.inputs.len(),
                    if self.inputs.len() == 1 { "" } else { "s" }
                ),
                reconstruction: PathBuf::new(),
                comparison: None,
            },
        );
        let page_ms = 1e3 * page_start.elapsed().as_secs_f64();
        // The page's own time goes into report.json only: the page, made from it, cannot show it.
        edit_report(&mut files, |report| {
            if let Some(list) = report["timings"].as_array_mut() {
                list.push(serde_json::json!({ "stage": "report page", "ms": page_ms }));
            }
        })?;
        files.push(("report.html".into(), page.into_bytes()));
        Ok(files)
    }
}

/// [`PhotoSet::photo_outputs`]' answer.
struct PhotoOutputs {
    files: Vec<(PathBuf, Vec<u8>)>,
    warnings: Vec<String>,
    seconds: f64,
}

/// Applies `edit` to `report.json` among `files` (parsed, then written back as before), if it
/// is there.
fn edit_report(
    files: &mut [(PathBuf, Vec<u8>)],
    edit: impl FnOnce(&mut serde_json::Value),
) -> Result<(), PipelineError> {
    let Some((_, bytes)) = files.iter_mut().find(|(p, _)| p == Path::new("report.json")) else {
        return Ok(());
    };
    let encode = |e: serde_json::Error| PipelineError::Encode {
        file: "report.json".into(),
        message: e.to_string(),
    };
    let mut report: serde_json::Value = serde_json::from_slice(bytes).map_err(encode)?;
    edit(&mut report);
    *bytes = serde_json::to_vec_pretty(&report).map_err(encode)?;
    Ok(())
}

/// `overlays/NAME.jpg` for every record with a photo ([`crate::report::draw_overlay`]), and
/// `NAME.pts` in `landmark_folder` for every detected one; the overlays of a reconstruction's
/// photos carry its fitted points and each photo's fate. A photo whose overlay cannot be
/// encoded gets a warning instead.
pub(crate) fn photo_files(
    records: &[PhotoRecord],
    landmark_folder: &Path,
    inputs: &[Input],
    result: Option<&Reconstruction>,
    warnings: &mut Vec<String>,
) -> Vec<(PathBuf, Vec<u8>)> {
    use crate::report::{Overlay, PhotoStatus, draw_overlay};
    // Each photo's files, or why its overlay is missing; the photos in parallel, their files
    // in the records' order.
    type PhotoOutputs = (Vec<(PathBuf, Vec<u8>)>, Option<String>);
    let per_photo: Vec<PhotoOutputs> = records
        .par_iter()
        .map(|record| {
            let mut files = Vec::new();
            if record.detected {
                files.push((
                    landmark_folder.join(format!("{}.pts", record.name)),
                    crate::landmarks::format_pts(&record.landmarks).into_bytes(),
                ));
            }
            let input = inputs.iter().find(|i| i.points.name == record.name);
            let image = match (
                &record.image,
                &record.skipped,
                input.and_then(|i| i.image.as_ref()),
            ) {
                (Some(image), _, _) => image,
                (None, None, Some(photo)) => &photo.colour,
                _ => return (files, None), // an undecodable photo, or a points-only run: no picture
            };
            let mut notes = Vec::new();
            let mut fitted = None;
            let status = match (&record.skipped, result) {
                (Some(why), _) => PhotoStatus::Skipped(why.clone()),
                (None, Some(result)) => {
                    if let Some(d) = result.dropped.iter().find(|d| d.name == record.name) {
                        PhotoStatus::Dropped(d.reason.clone())
                    } else {
                        if let Some(slot) = result.photo_fits.iter().position(|f| f.name == record.name) {
                            let fit = &result.photo_fits[slot];
                            let [yaw, pitch, roll] = result.depth.photos[slot].pose.yaw_pitch_roll_degrees();
                            notes.push(format!(
                                "yaw {yaw:.1}°, pitch {pitch:.1}°, roll {roll:.1}°; the fitted face's points lie {:.1} px RMS from the photo's",
                                fit.rms_pixels
                            ));
                            if let Some(input) = input {
                                fitted = Some((input.points.points.as_slice(), fit.points.as_slice()));
                            }
                        }
                        PhotoStatus::Used
                    }
                }
                (None, None) => PhotoStatus::Landmarked,
            };
            if record.detected && record.skipped.is_none() {
                notes.push(format!(
                    "landmarks: {}",
                    landmark_folder.join(format!("{}.pts", record.name)).display()
                ));
            }
            let picture = draw_overlay(&Overlay {
                image,
                name: &record.name,
                status: &status,
                notes: &notes,
                face_box: record.face_box,
                landmarks: &record.landmarks,
                fitted,
            });
            match crate::io::encode_jpeg(&picture, crate::io::JPEG_QUALITY) {
                Ok(jpeg) => {
                    files.push((Path::new("overlays").join(format!("{}.jpg", record.name)), jpeg));
                    (files, None)
                }
                Err(e) => (files, Some(format!("{}: its overlay could not be encoded: {e}", record.name))),
            }
        })
        .collect();
    let mut files = Vec::new();
    for (photo_files, warning) in per_photo {
        files.extend(photo_files);
        warnings.extend(warning);
    }
    files
}

/// [`landmark_photos`]' answer.
#[derive(Debug, Clone)]
pub struct LandmarkedPhotos {
    /// What became of each photo, in the order given: `PATH: 68 points, face box …` or
    /// `PATH: skipped: reason`, then any note about an overlay that could not be drawn.
    pub lines: Vec<String>,
    /// The files, `(path, bytes)`: `NAME.pts` for each landmarked photo (where `reconstruct
    /// --landmarks DIR` looks), with `json` also `NAME.json` ([`crate::landmarks`]' JSON
    /// form), and `overlays/NAME.jpg` for each decoded photo.
    pub files: Vec<(PathBuf, Vec<u8>)>,
}

/// Detects and landmarks the subject of each photo (`splineface landmarks`): the photos
/// decoded, detected and landmarked in parallel, gathered in their order; a photo whose name
/// another has already taken is skipped.
///
/// # Errors
/// [`InputError::NoneLandmarked`] with every photo's fate when none gave landmarks;
/// [`InputError::LandmarkFile`] if a photo's landmarks cannot be written as JSON (they are
/// finite, so it does not happen).
pub fn landmark_photos(
    paths: &[PathBuf],
    model: &ShapePredictor,
    json: bool,
) -> Result<LandmarkedPhotos, InputError> {
    let mut lines: Vec<String> = Vec::new();
    let mut names = std::collections::BTreeSet::new();
    let mut unique: Vec<(&Path, String)> = Vec::new();
    for path in paths {
        let stem = photo_stem(path);
        if names.insert(stem.clone()) {
            unique.push((path, stem));
        } else {
            lines.push(format!(
                "{}: skipped: another photo has the name `{stem}`",
                path.display()
            ));
        }
    }
    type Landmarked = (String, Option<PhotoRecord>, Option<(PathBuf, Vec<u8>)>);
    let results: Vec<Landmarked> = unique
        .par_iter()
        .map(|(path, stem)| -> Result<Landmarked, InputError> {
            let decoded = match crate::align::decode_photo(path) {
                Ok(d) => d,
                Err(e) => return Ok((format!("{}: skipped: {}", path.display(), e.problem), None, None)),
            };
            match landmark_photo(model, &decoded, stem) {
                Ok((_, found, _)) => {
                    let b = found.face.bbox;
                    let mut line = format!(
                        "{}: 68 points, face box {}×{} at ({}, {}), mirror disagreement {:.1}% of the eye width",
                        path.display(),
                        b.right - b.left + 1,
                        b.bottom - b.top + 1,
                        b.left,
                        b.top,
                        100.0 * found.disagreement
                    );
                    if let Some(note) = &found.note {
                        line.push_str(&format!("; {note}"));
                    }
                    let json_file = if json {
                        let landmarks = crate::landmarks::Landmarks {
                            scheme: crate::landmarks::Scheme::Ibug68,
                            points: LandmarkPoints::Planar(found.ibug.clone()),
                        };
                        let text = crate::landmarks::format_landmarks_json(&landmarks).map_err(|e| {
                            InputError::LandmarkFile {
                                path: path.to_path_buf(),
                                message: format!("its landmarks: {e}"),
                            }
                        })?;
                        Some((PathBuf::from(format!("{stem}.json")), text.into_bytes()))
                    } else {
                        None
                    };
                    let record = PhotoRecord {
                        image: Some(decoded.to_rgb8()),
                        ..PhotoRecord::from_detection(stem, &found)
                    };
                    Ok((line, Some(record), json_file))
                }
                Err(reason) => Ok((
                    format!("{}: skipped: {reason}", path.display()),
                    Some(PhotoRecord::skipped(stem, Some(decoded.to_rgb8()), reason.to_string())),
                    None,
                )),
            }
        })
        .collect::<Result<_, _>>()?;
    let mut records = Vec::new();
    let mut files = Vec::new();
    let mut found_any = false;
    for (line, record, json_file) in results {
        lines.push(line);
        found_any |= record.as_ref().is_some_and(|r| r.detected);
        records.extend(record);
        files.extend(json_file);
    }
    if !found_any {
        return Err(InputError::NoneLandmarked { lines });
    }
    // The `.pts` files at the top, so that `reconstruct --landmarks DIR` reads them.
    files.extend(photo_files(&records, Path::new(""), &[], None, &mut lines));
    Ok(LandmarkedPhotos { lines, files })
}
