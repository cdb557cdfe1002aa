//! Many subjects, one folder each: `splineface batch` and the Python package's
//! `reconstruct_subject` (which a Dask cluster maps over subjects).
//!
//! A subject is a sub-folder of the batch's root holding its photos and/or landmark files
//! ([`crate::pipeline::IMAGE_EXTENSIONS`], [`crate::pipeline::LANDMARK_EXTENSIONS`]; landmark
//! files are matched to photos by name, photos without one are detected and landmarked with the
//! model). Its outputs go to `OUT/NAME/`, the files `splineface reconstruct` writes, with
//! [`STATE_FILE`] last: the subject's [`SubjectRow`] and a fingerprint of everything its
//! outputs depend on (the inputs' bytes, the options, the model's and the reference's
//! identity, splineface's version). A later run whose fingerprint matches skips the subject
//! ([`Status::Unchanged`]), so an interrupted batch resumes where it stopped. A subject that
//! fails is a row with its message; it never stops the batch. [`write_summary`] writes
//! `summary.csv` and `summary.jsonl`, one row per subject.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::Real;
use crate::io::OutputError;
use crate::io::fnv1a64_hex;
use crate::landmarker::ShapePredictor;
use crate::pipeline::{
    IMAGE_EXTENSIONS, LANDMARK_EXTENSIONS, PipelineOptions, files_in, gather_inputs, reconstruct,
};
use crate::reference::ReferenceFace;

/// The file in each subject's output folder that records its row and fingerprint.
pub const STATE_FILE: &str = "batch-state.json";

/// Why a batch cannot start, or its summary cannot be written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BatchError {
    /// The root is not a folder.
    #[error("{}: not a folder", path.display())]
    NotAFolder {
        /// The root.
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
    /// A file could not be read.
    #[error("cannot read {}: {error}", path.display())]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The root holds no sub-folders.
    #[error(
        "{}: no subject folders (one sub-folder per subject, holding its photos and/or landmark files)",
        path.display()
    )]
    NoSubjects {
        /// The root.
        path: PathBuf,
    },
    /// The output folder lies inside the input.
    #[error(
        "{}: the output lies inside the input folder {}; choose a folder outside it",
        out.display(),
        root.display()
    )]
    OutputInsideInput {
        /// The output folder.
        out: PathBuf,
        /// The root.
        root: PathBuf,
    },
    /// The output folder cannot be used.
    #[error(transparent)]
    Output(#[from] OutputError),
}

/// One subject: its name (the folder's) and folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Subject {
    /// The sub-folder's name.
    pub name: String,
    /// The sub-folder.
    pub folder: PathBuf,
}

/// The subjects under `root`: its sub-folders, by name (hidden ones, starting with `.`, left
/// out).
///
/// # Errors
/// [`BatchError::NotAFolder`], [`BatchError::Directory`] or [`BatchError::NoSubjects`].
pub fn subjects(root: &Path) -> Result<Vec<Subject>, BatchError> {
    if !root.is_dir() {
        return Err(BatchError::NotAFolder {
            path: root.to_path_buf(),
        });
    }
    let entries = std::fs::read_dir(root).map_err(|error| BatchError::Directory {
        path: root.to_path_buf(),
        error,
    })?;
    let mut subjects: Vec<Subject> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .filter_map(|folder| {
            let name = folder.file_name()?.to_string_lossy().into_owned();
            (!name.starts_with('.')).then_some(Subject { name, folder })
        })
        .collect();
    if subjects.is_empty() {
        return Err(BatchError::NoSubjects {
            path: root.to_path_buf(),
        });
    }
    subjects.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(subjects)
}

/// `path` made absolute with its existing part's symbolic links resolved (the rest, not yet
/// created, appended as given).
fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    while !existing.exists() {
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_owned());
                existing = parent;
            }
            _ => return absolute,
        }
    }
    let mut out = existing.canonicalize().unwrap_or_else(|_| existing.to_path_buf());
    out.extend(rest.iter().rev());
    out
}

/// Checks, before any work, that `out` can hold a batch of `root`'s subjects: it is not inside
/// `root` (its folders would become subjects of the next run) and can be written.
///
/// # Errors
/// [`BatchError::OutputInsideInput`] or [`BatchError::Output`].
pub fn check_output(root: &Path, out: &Path) -> Result<(), BatchError> {
    if resolved(out).starts_with(resolved(root)) {
        return Err(BatchError::OutputInsideInput {
            out: out.to_path_buf(),
            root: root.to_path_buf(),
        });
    }
    Ok(crate::io::check_output_dir(out)?)
}

/// What became of a subject.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Reconstructed in this run.
    Done,
    /// Skipped: its outputs are from unchanged inputs and options.
    Unchanged,
    /// It could not be reconstructed ([`SubjectRow::message`] says why).
    Failed,
}

impl Status {
    /// `done`, `unchanged` or `failed`.
    pub fn name(self) -> &'static str {
        match self {
            Status::Done => "done",
            Status::Unchanged => "unchanged",
            Status::Failed => "failed",
        }
    }
}

/// One subject's line of the summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubjectRow {
    /// The subject's name.
    pub subject: String,
    /// What became of it.
    pub status: Status,
    /// Photos (or, points-only, landmark files) found in its folder.
    pub photos_given: usize,
    /// Photos the face was made from.
    pub photos_used: usize,
    /// Photos left out by the reconstruction (their landmarks disagreed, or their pose).
    pub photos_dropped: usize,
    /// Photos skipped before it (undecodable, no face, bad landmark file).
    pub photos_skipped: usize,
    /// Wall time of the subject in the run that made its outputs, seconds.
    pub seconds: Real,
    /// Each stage's wall time in that run, milliseconds, as `report.json` lists them.
    pub stage_ms: Vec<(String, Real)>,
    /// The structure's similarity to the reference (the depth stage's SIM).
    pub similarity: Option<Real>,
    /// The median over the used photos of the fitted face's RMS distance from each photo's
    /// points, pixels.
    pub fit_rms_pixels: Option<Real>,
    /// Whether the refinement by the photos' pixels was kept (`None` when it did not run).
    pub refined: Option<bool>,
    /// The mesh's vertex count.
    pub vertices: Option<usize>,
    /// Why it failed; empty otherwise.
    pub message: String,
}

impl SubjectRow {
    fn failed(subject: &Subject, photos_given: usize, seconds: Real, message: String) -> Self {
        SubjectRow {
            subject: subject.name.clone(),
            status: Status::Failed,
            photos_given,
            photos_used: 0,
            photos_dropped: 0,
            photos_skipped: 0,
            seconds,
            stage_ms: Vec::new(),
            similarity: None,
            fit_rms_pixels: None,
            refined: None,
            vertices: None,
            message,
        }
    }
}

/// What the subjects of a batch share.
#[derive(Debug, Clone)]
pub struct BatchJob<'a> {
    /// The landmark model for photos without a landmark file.
    pub model: Option<&'a ShapePredictor>,
    /// The model's identity in the fingerprint (e.g. a hash of its file).
    pub model_identity: String,
    /// The reference face.
    pub reference: &'a ReferenceFace,
    /// The reference's identity in the fingerprint.
    pub reference_identity: String,
    /// The pipeline's options.
    pub options: PipelineOptions,
    /// Reconstruct every subject, unchanged or not.
    pub force: bool,
}

/// The state file's contents.
#[derive(Debug, Serialize, Deserialize)]
struct State {
    format: String,
    fingerprint: String,
    row: SubjectRow,
}

const STATE_FORMAT: &str = "splineface/batch-state";

/// A subject's input files: its photos and landmark files, by name.
fn input_files(folder: &Path) -> Result<(Vec<PathBuf>, Vec<PathBuf>), String> {
    let photos = files_in(folder, &IMAGE_EXTENSIONS).map_err(|e| e.to_string())?;
    let landmarks = files_in(folder, &LANDMARK_EXTENSIONS).map_err(|e| e.to_string())?;
    Ok((photos, landmarks))
}

/// A file's identity in a batch's fingerprints: its length and FNV-1a hash, `"LENGTH HASH"`;
/// `"none"` without a file (no model, the embedded reference).
///
/// # Errors
/// [`BatchError::Unreadable`] (within [`crate::io::MAX_LARGE_INPUT_BYTES`]).
pub fn file_identity(path: Option<&Path>) -> Result<String, BatchError> {
    let Some(path) = path else {
        return Ok("none".to_owned());
    };
    let bytes = crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES).map_err(|error| {
        BatchError::Unreadable {
            path: path.to_path_buf(),
            error,
        }
    })?;
    Ok(format!("{} {}", bytes.len(), fnv1a64_hex(&bytes)))
}

/// The fingerprint of everything a subject's outputs depend on.
fn fingerprint(files: &[PathBuf], job: &BatchJob<'_>) -> Result<String, String> {
    let mut text = format!(
        "splineface {}\noptions {:?}\nmodel {}\nreference {}\n",
        env!("CARGO_PKG_VERSION"),
        job.options,
        job.model_identity,
        job.reference_identity
    );
    for file in files {
        let identity = file_identity(Some(file)).map_err(|e| e.to_string())?;
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        text.push_str(&format!("{name} {identity}\n"));
    }
    Ok(fnv1a64_hex(text.as_bytes()))
}

/// The row recorded in `folder`'s state file, if its fingerprint is `fingerprint` and the
/// subject was done.
fn unchanged(folder: &Path, fingerprint: &str) -> Option<SubjectRow> {
    let text = std::fs::read_to_string(folder.join(STATE_FILE)).ok()?;
    let state: State = serde_json::from_str(&text).ok()?;
    (state.format == STATE_FORMAT && state.fingerprint == fingerprint && state.row.status == Status::Done)
        .then_some(state.row)
}

/// Reconstructs one subject into `out/NAME/` (see the module documentation), or finds its
/// outputs up to date. Never fails: a failure is a [`Status::Failed`] row with its message,
/// and leaves the subject's earlier outputs as they were.
pub fn run_subject(subject: &Subject, out: &Path, job: &BatchJob<'_>) -> SubjectRow {
    let start = Instant::now();
    let elapsed = || start.elapsed().as_secs_f64();
    let (photos, landmarks) = match input_files(&subject.folder) {
        Ok(files) => files,
        Err(message) => return SubjectRow::failed(subject, 0, elapsed(), message),
    };
    let photos_given = if photos.is_empty() {
        landmarks.len()
    } else {
        photos.len()
    };
    if photos.is_empty() && landmarks.is_empty() {
        return SubjectRow::failed(
            subject,
            0,
            elapsed(),
            format!("{}: no photos or landmark files", subject.folder.display()),
        );
    }
    if !photos.is_empty() && landmarks.is_empty() && job.model.is_none() {
        return SubjectRow::failed(
            subject,
            photos_given,
            elapsed(),
            format!(
                "{}: photos without landmark files, and no landmark model to find their landmarks",
                subject.folder.display()
            ),
        );
    }
    let all: Vec<PathBuf> = photos.iter().chain(&landmarks).cloned().collect();
    let fingerprint = match fingerprint(&all, job) {
        Ok(f) => f,
        Err(message) => return SubjectRow::failed(subject, photos_given, elapsed(), message),
    };
    let folder = out.join(&subject.name);
    if !job.force
        && let Some(row) = unchanged(&folder, &fingerprint)
    {
        return SubjectRow {
            status: Status::Unchanged,
            ..row
        };
    }
    let made = (|| -> Result<SubjectRow, String> {
        let set = gather_inputs(&photos, Some(&subject.folder), job.model).map_err(|e| e.to_string())?;
        set.check_count(job.options.min_photos)
            .map_err(|e| e.to_string())?;
        let result =
            reconstruct(&set.inputs, job.reference, &job.options, |_| {}).map_err(|e| e.to_string())?;
        let mut files = set.files(&result, None).map_err(|e| e.to_string())?;
        let mut fits: Vec<Real> = result.photo_fits.iter().map(|f| f.rms_pixels).collect();
        fits.sort_by(Real::total_cmp);
        let mut stage_ms: Vec<(String, Real)> = set
            .seconds
            .map(|s| ("photos".to_owned(), 1e3 * s))
            .into_iter()
            .collect();
        stage_ms.extend(result.timings.iter().map(|(stage, s)| (stage.clone(), 1e3 * s)));
        let row = SubjectRow {
            subject: subject.name.clone(),
            status: Status::Done,
            photos_given,
            photos_used: result.depth.photos.len(),
            photos_dropped: result.dropped.len(),
            photos_skipped: set.skipped.len(),
            seconds: elapsed(),
            stage_ms,
            similarity: Some(result.depth.similarity),
            fit_rms_pixels: fits.get(fits.len() / 2).copied(),
            refined: result.refinement.as_ref().map(|r| r.accepted),
            vertices: Some(result.mesh.mesh.positions().len()),
            message: String::new(),
        };
        let state = State {
            format: STATE_FORMAT.to_owned(),
            fingerprint: fingerprint.clone(),
            row: row.clone(),
        };
        let state = serde_json::to_vec_pretty(&state).map_err(|e| e.to_string())?;
        // The state goes last: a subject killed while its files are renamed into place is
        // not taken as done.
        files.push((STATE_FILE.into(), state));
        crate::io::write_into(&folder, &files).map_err(|e| e.to_string())?;
        Ok(row)
    })();
    made.unwrap_or_else(|message| SubjectRow::failed(subject, photos_given, elapsed(), message))
}

/// A CSV field: quoted when it holds a comma, a quote or a line break.
fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_owned()
    }
}

/// The columns of `summary.csv`.
pub const SUMMARY_COLUMNS: [&str; 12] = [
    "subject",
    "status",
    "photos_given",
    "photos_used",
    "photos_dropped",
    "photos_skipped",
    "seconds",
    "similarity",
    "fit_rms_pixels",
    "refined",
    "vertices",
    "message",
];

/// `summary.csv` (the columns of [`SUMMARY_COLUMNS`]) and `summary.jsonl` (each row whole,
/// stage times included) of `rows`, as `(name, bytes)`.
pub(crate) fn summary_files(rows: &[SubjectRow]) -> Vec<(PathBuf, Vec<u8>)> {
    let option = |v: Option<String>| v.unwrap_or_default();
    let mut csv = SUMMARY_COLUMNS.join(",") + "\n";
    let mut jsonl = String::new();
    for r in rows {
        let fields = [
            csv_field(&r.subject),
            r.status.name().to_owned(),
            r.photos_given.to_string(),
            r.photos_used.to_string(),
            r.photos_dropped.to_string(),
            r.photos_skipped.to_string(),
            format!("{:.3}", r.seconds),
            option(r.similarity.map(|s| format!("{s:.6}"))),
            option(r.fit_rms_pixels.map(|s| format!("{s:.3}"))),
            option(r.refined.map(|b| b.to_string())),
            option(r.vertices.map(|v| v.to_string())),
            csv_field(&r.message),
        ];
        csv.push_str(&fields.join(","));
        csv.push('\n');
        // A row always serialises (plain data, finite or null numbers).
        jsonl.push_str(&serde_json::to_string(r).unwrap_or_default());
        jsonl.push('\n');
    }
    vec![
        ("summary.csv".into(), csv.into_bytes()),
        ("summary.jsonl".into(), jsonl.into_bytes()),
    ]
}

/// Runs every subject ([`run_subject`]) in parallel (each subject's stages are parallel too;
/// rayon shares the cores), calling `done` with each finished row and how many have finished,
/// from whichever thread finished it. Returns the rows in the subjects' order.
pub fn run_subjects(
    subjects: &[Subject],
    out: &Path,
    job: &BatchJob<'_>,
    done: impl Fn(&SubjectRow, usize) + Sync,
) -> Vec<SubjectRow> {
    use rayon::prelude::*;
    let finished = std::sync::atomic::AtomicUsize::new(0);
    subjects
        .par_iter()
        .map(|subject| {
            let row = run_subject(subject, out, job);
            done(
                &row,
                finished.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1,
            );
            row
        })
        .collect()
}

/// How many rows have each status: done, unchanged, failed.
pub fn status_counts(rows: &[SubjectRow]) -> [usize; 3] {
    let count = |s: Status| rows.iter().filter(|r| r.status == s).count();
    [
        count(Status::Done),
        count(Status::Unchanged),
        count(Status::Failed),
    ]
}

/// Writes `summary.csv` and `summary.jsonl` into `out`, all or nothing.
///
/// # Errors
/// [`BatchError::Output`] naming the file that could not be written.
pub fn write_summary(out: &Path, rows: &[SubjectRow]) -> Result<(), BatchError> {
    Ok(crate::io::write_into(out, &summary_files(rows))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_fields_with_commas_quotes_and_lines_are_quoted() {
        assert_eq!(csv_field("plain"), "plain");
        assert_eq!(csv_field("a, b"), "\"a, b\"");
        assert_eq!(csv_field("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(csv_field("two\nlines"), "\"two\nlines\"");
    }

    #[test]
    fn an_output_inside_the_input_is_refused() {
        let root = std::env::temp_dir().join(format!("splineface-batch-{}", std::process::id()));
        std::fs::create_dir_all(root.join("alice")).unwrap();
        let inside = check_output(&root, &root.join("out/new"));
        assert!(
            matches!(inside, Err(BatchError::OutputInsideInput { .. })),
            "{inside:?}"
        );
        // Through `..` and a path not yet made, still inside.
        let sneaky = check_output(&root, &root.join("alice/../results"));
        assert!(
            matches!(sneaky, Err(BatchError::OutputInsideInput { .. })),
            "{sneaky:?}"
        );
        let beside = root.with_extension("out");
        assert!(check_output(&root, &beside).is_ok());
        std::fs::remove_dir_all(&root).unwrap();
    }
}
