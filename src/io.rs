//! Reading input files within limits, and writing output files without leaving partial files
//! behind.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// The largest landmark or settings file read: 64 MiB (a 68-point file is about 1 KB).
pub const MAX_SMALL_INPUT_BYTES: u64 = 64 << 20;

/// The largest surface, reference or model file read: 1 GiB (dlib's 68-point model is 99 MB,
/// the embedded reference 0.3 MB).
pub const MAX_DATA_INPUT_BYTES: u64 = 1 << 30;

/// The largest mesh or photo file read: 4 GiB.
pub const MAX_LARGE_INPUT_BYTES: u64 = 4 << 30;

/// Opens an input file for reading, if it is a regular, non-empty file of at most `limit`
/// bytes (its length is the file's metadata's); see [`read_input`].
///
/// `std::fs::read` would read a device such as `/dev/zero` or a named pipe until memory runs
/// out or forever, and a directory gives a terse OS error; these are refused up front, with an
/// error saying what the path is.
///
/// # Errors
/// `NotFound` and other OS errors as they come; `InvalidInput` for a directory, a special file
/// or an oversized file; `InvalidData` for an empty file (no input this crate reads can be
/// empty).
pub fn open_input(path: &Path, limit: u64) -> std::io::Result<std::fs::File> {
    let refuse = |message: String| Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, message));
    // Looked at before opening: opening a named pipe blocks until someone writes to it.
    let metadata = std::fs::metadata(path)?;
    if metadata.is_dir() {
        return refuse("it is a directory, not a file".to_owned());
    }
    if !metadata.is_file() {
        return refuse("it is not a regular file (a device, pipe or socket)".to_owned());
    }
    let file = std::fs::File::open(path)?;
    let metadata = file.metadata()?;
    if !metadata.is_file() {
        return refuse("it is not a regular file (it changed while being opened)".to_owned());
    }
    if metadata.len() == 0 {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "the file is empty",
        ));
    }
    if metadata.len() > limit {
        return refuse(format!(
            "it is {} bytes, more than the {} this input may have",
            metadata.len(),
            limit
        ));
    }
    Ok(file)
}

/// Reads an input file whole, if it is a regular file of at most `limit` bytes
/// ([`open_input`]). The size is checked before reading and the read is capped at it, so a
/// file that grows meanwhile cannot exceed the limit either.
///
/// # Errors
/// As [`open_input`], and `InvalidInput` for a file that grew past the limit while read.
pub fn read_input(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let file = open_input(path, limit)?;
    let length = file.metadata()?.len();
    let mut bytes = Vec::with_capacity(usize::try_from(length).unwrap_or(0));
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("it grew past {limit} bytes while being read"),
        ));
    }
    Ok(bytes)
}

/// The bytes as UTF-8 text (a leading byte-order mark dropped), or what they are instead.
///
/// # Errors
/// A message naming UTF-16 (which some Windows tools write) or the first byte that is not
/// UTF-8.
pub(crate) fn utf8_text(bytes: &[u8]) -> Result<&str, String> {
    let bytes = bytes.strip_prefix(b"\xef\xbb\xbf").unwrap_or(bytes);
    if bytes.starts_with(b"\xff\xfe") || bytes.starts_with(b"\xfe\xff") {
        return Err("the text is UTF-16; save it as UTF-8".to_owned());
    }
    std::str::from_utf8(bytes).map_err(|e| format!("the file is not UTF-8 text (byte {})", e.valid_up_to()))
}

/// A `serde_json` error's message without the ` at line L column C` it appends, for callers
/// that report the position themselves.
pub(crate) fn json_message(error: &serde_json::Error) -> String {
    let message = error.to_string();
    let suffix = format!(" at line {} column {}", error.line(), error.column());
    match message.strip_suffix(&suffix) {
        Some(bare) => format!("{bare} (column {})", error.column()),
        None => message,
    }
}

/// [`read_input`] for text: the bytes must be UTF-8 (a leading byte-order mark is dropped).
///
/// # Errors
/// As [`read_input`], and `InvalidData` naming the first byte that is not UTF-8 (UTF-16 files
/// from some Windows tools are recognised and named as such).
pub fn read_input_text(path: &Path, limit: u64) -> std::io::Result<String> {
    let bytes = read_input(path, limit)?;
    utf8_text(&bytes)
        .map(str::to_owned)
        .map_err(|message| std::io::Error::new(std::io::ErrorKind::InvalidData, message))
}

/// The temporary a file is staged in before it is renamed over `path`: `.NAME.PID.tmp` in the
/// same directory (a rename across file systems would not be atomic).
fn temporary_for(path: &Path) -> std::io::Result<std::path::PathBuf> {
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} is not a file path", path.display()),
        )
    })?;
    let mut temporary_name = std::ffi::OsString::from(".");
    temporary_name.push(name);
    temporary_name.push(format!(".{}.tmp", std::process::id()));
    Ok(directory_of(path).join(temporary_name))
}

fn directory_of(path: &Path) -> &Path {
    match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    }
}

/// Writes `bytes` to a new temporary beside `path` and flushes it to disk; returns its path.
/// On failure nothing is left.
fn stage(path: &Path, bytes: &[u8]) -> std::io::Result<std::path::PathBuf> {
    let temporary = temporary_for(path)?;
    let result = (|| {
        let mut file = std::fs::File::create(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()
    })();
    match result {
        Ok(()) => Ok(temporary),
        Err(e) => {
            let _ = std::fs::remove_file(&temporary);
            Err(e)
        }
    }
}

/// Removes temporaries that killed runs left beside `path` (`.NAME.PID.tmp` whose process is
/// gone). Only on Linux, where `/proc` tells which processes live; elsewhere they stay.
fn remove_stale_temporaries(path: &Path) {
    if !cfg!(target_os = "linux") {
        return;
    }
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
        return;
    };
    let prefix = format!(".{name}.");
    let Ok(entries) = std::fs::read_dir(directory_of(path)) else {
        return;
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(pid) = file_name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|rest| rest.strip_suffix(".tmp"))
            .and_then(|pid| pid.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id()
            && !Path::new("/proc").join(pid.to_string()).exists()
            && entry.file_type().is_ok_and(|t| t.is_file())
        {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// Writes `bytes` to `path` all or nothing: the bytes go to a temporary file in the same
/// directory, which is flushed to disk and then renamed over `path`. If anything fails, the
/// temporary file is removed and `path` is untouched. Temporaries that killed runs left beside
/// `path` are removed first.
///
/// # Errors
/// The I/O error, with the path it concerns.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    remove_stale_temporaries(path);
    let temporary = stage(path, bytes)?;
    std::fs::rename(&temporary, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&temporary);
    })
}

/// Writes several files in two phases: first every file's bytes go to a temporary beside it,
/// flushed to disk (the files side by side); only when all are staged are they renamed over
/// their paths, one after the other. A run killed while computing or staging leaves every
/// previous output untouched (and temporaries, which the next write of those paths removes);
/// only a kill within the renames, a few syscalls long, leaves some files new and some old,
/// each of them whole.
///
/// If staging fails, the temporaries are removed and nothing changed; the error names the
/// first file in `files`' order that failed. If a rename fails, the files this call already
/// renamed into place are removed as well, so a failed call leaves none of its files (it does
/// not restore files they replaced).
///
/// # Errors
/// The path that failed and its I/O error.
pub fn write_files_atomically(
    files: &[(std::path::PathBuf, Vec<u8>)],
) -> Result<(), (std::path::PathBuf, std::io::Error)> {
    stage_and_rename(files)
}

/// [`write_files_atomically`] of owned or borrowed bytes.
fn stage_and_rename<B: AsRef<[u8]> + Sync>(
    files: &[(std::path::PathBuf, B)],
) -> Result<(), (std::path::PathBuf, std::io::Error)> {
    use rayon::prelude::*;
    // The files are staged side by side: their flushes to disk then overlap (a file system
    // commits them together) rather than waiting for one another.
    let results: Vec<std::io::Result<std::path::PathBuf>> = files
        .par_iter()
        .map(|(path, bytes)| {
            remove_stale_temporaries(path);
            stage(path, bytes.as_ref())
        })
        .collect();
    let mut staged = Vec::with_capacity(files.len());
    let mut failure = None;
    for (k, result) in results.into_iter().enumerate() {
        match result {
            Ok(temporary) => staged.push(temporary),
            // The first failure in the files' order is the one reported.
            Err(e) => {
                failure.get_or_insert((k, e));
            }
        }
    }
    if let Some((k, e)) = failure {
        for temporary in &staged {
            let _ = std::fs::remove_file(temporary);
        }
        return Err((files[k].0.clone(), e));
    }
    for (k, ((path, _), temporary)) in files.iter().zip(&staged).enumerate() {
        if let Err(e) = std::fs::rename(temporary, path) {
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(done);
            }
            for temporary in &staged[k..] {
                let _ = std::fs::remove_file(temporary);
            }
            return Err((path.clone(), e));
        }
    }
    Ok(())
}

/// Why an output folder cannot be used or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OutputError {
    /// The path exists and is a file.
    #[error("{}: exists and is not a directory", path.display())]
    NotADirectory {
        /// The output folder.
        path: PathBuf,
    },
    /// The folder cannot be created: an ancestor is a file.
    #[error("{}: cannot be created, {} is not a directory", path.display(), ancestor.display())]
    AncestorNotADirectory {
        /// The output folder.
        path: PathBuf,
        /// Its nearest existing ancestor.
        ancestor: PathBuf,
    },
    /// No file can be made where the folder is or would be.
    #[error("{}: cannot write there: cannot create a file in {}: {error}", path.display(), directory.display())]
    NotWritable {
        /// The output folder.
        path: PathBuf,
        /// The folder tried.
        directory: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// An output file's path is a folder.
    #[error("{}: is a directory", path.display())]
    IsADirectory {
        /// The output file.
        path: PathBuf,
    },
    /// An output file's folder does not exist.
    #[error("{}: the directory {} does not exist", path.display(), directory.display())]
    NoSuchDirectory {
        /// The output file.
        path: PathBuf,
        /// Its folder.
        directory: PathBuf,
    },
    /// An output file's folder is a file.
    #[error("{}: {} is not a directory", path.display(), directory.display())]
    ParentNotADirectory {
        /// The output file.
        path: PathBuf,
        /// Its would-be folder.
        directory: PathBuf,
    },
    /// A folder could not be created.
    #[error("cannot create {}: {error}", path.display())]
    CreateDirectory {
        /// The folder.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {}: {error}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        error: std::io::Error,
    },
}

/// Checks, before any work, that `out` can be the output folder: it is a folder or can be
/// created as one (its nearest existing ancestor is a folder in which a file can be made).
/// Catches a file in the way, a read-only file system or a missing permission up front rather
/// than after minutes of computing.
///
/// # Errors
/// [`OutputError::NotADirectory`], [`OutputError::AncestorNotADirectory`] or
/// [`OutputError::NotWritable`].
pub fn check_output_dir(out: &Path) -> Result<(), OutputError> {
    if out.exists() && !out.is_dir() {
        return Err(OutputError::NotADirectory {
            path: out.to_path_buf(),
        });
    }
    let existing = out
        .ancestors()
        .map(|a| {
            if a.as_os_str().is_empty() {
                Path::new(".")
            } else {
                a
            }
        })
        .find(|a| a.exists())
        .unwrap_or(Path::new("."));
    if !existing.is_dir() {
        return Err(OutputError::AncestorNotADirectory {
            path: out.to_path_buf(),
            ancestor: existing.to_path_buf(),
        });
    }
    probe_writable(existing).map_err(|error| OutputError::NotWritable {
        path: out.to_path_buf(),
        directory: existing.to_path_buf(),
        error,
    })
}

/// Checks, before any work, that the output file `path` can be written: it is not a folder,
/// its folder exists and a file can be made in it.
///
/// # Errors
/// [`OutputError::IsADirectory`], [`OutputError::NoSuchDirectory`],
/// [`OutputError::ParentNotADirectory`] or [`OutputError::NotWritable`].
pub fn check_output_file(path: &Path) -> Result<(), OutputError> {
    let path_buf = || path.to_path_buf();
    if path.is_dir() {
        return Err(OutputError::IsADirectory { path: path_buf() });
    }
    let directory = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !directory.exists() {
        return Err(OutputError::NoSuchDirectory {
            path: path_buf(),
            directory: directory.to_path_buf(),
        });
    }
    if !directory.is_dir() {
        return Err(OutputError::ParentNotADirectory {
            path: path_buf(),
            directory: directory.to_path_buf(),
        });
    }
    probe_writable(directory).map_err(|error| OutputError::NotWritable {
        path: path_buf(),
        directory: directory.to_path_buf(),
        error,
    })
}

/// Makes and removes an empty file in `directory`: whether files can be made there.
///
/// # Errors
/// Why not.
pub(crate) fn probe_writable(directory: &Path) -> std::io::Result<()> {
    // Named like a temporary of `splineface-probe`, so that a probe a killed run left is
    // cleared by the next one as its temporaries are.
    let stem = directory.join("splineface-probe");
    remove_stale_temporaries(&stem);
    let probe = directory.join(format!(".splineface-probe.{}.tmp", std::process::id()));
    std::fs::File::create(&probe)?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Writes `files` (paths relative to `out`) into the folder `out`, creating it and the
/// sub-folders the paths name, all or nothing as [`write_files_atomically`] does.
///
/// # Errors
/// As [`check_output_dir`]; [`OutputError::CreateDirectory`] or [`OutputError::Write`] naming
/// the path that failed.
pub fn write_into(out: &Path, files: &[(PathBuf, Vec<u8>)]) -> Result<(), OutputError> {
    check_output_dir(out)?;
    let mut directories: Vec<PathBuf> = files
        .iter()
        .filter_map(|(p, _)| p.parent().map(|d| out.join(d)))
        .collect();
    directories.push(out.to_path_buf());
    directories.sort();
    directories.dedup();
    for d in &directories {
        std::fs::create_dir_all(d).map_err(|error| OutputError::CreateDirectory {
            path: d.clone(),
            error,
        })?;
    }
    let absolute: Vec<(PathBuf, &[u8])> = files.iter().map(|(p, b)| (out.join(p), b.as_slice())).collect();
    stage_and_rename(&absolute).map_err(|(path, error)| OutputError::Write { path, error })
}

/// A file that could not be encoded in memory: data the format cannot hold (a heatmap whose
/// values do not fill its size), or an encoder's own failure, which does not happen for valid
/// data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{format}: {message}")]
pub struct EncodeError {
    /// The format: `PNG`, `EXR`, ….
    pub format: &'static str,
    /// Why.
    pub message: String,
}

impl EncodeError {
    /// A `format` file that could not be encoded, and why.
    pub fn new(format: &'static str, message: impl std::fmt::Display) -> Self {
        EncodeError {
            format,
            message: message.to_string(),
        }
    }
}

/// Encodes an image (RGB, RGBA or grey, 8 or 16 bits) as PNG, with the `image` crate's
/// default compression. The bytes are the same on every run.
///
/// # Errors
/// The encoder's message (it does not fail for an image in memory).
///
/// # Examples
/// ```
/// let image = image::RgbImage::from_pixel(4, 3, image::Rgb([200, 120, 40]));
/// let png = splineface::io::encode_png(&image).unwrap();
/// assert!(png.starts_with(b"\x89PNG"));
/// ```
pub fn encode_png<P>(image: &image::ImageBuffer<P, Vec<P::Subpixel>>) -> Result<Vec<u8>, EncodeError>
where
    P: image::PixelWithColorType,
    [P::Subpixel]: image::EncodableLayout,
{
    let mut bytes = Vec::new();
    image
        .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| EncodeError::new("PNG", e))?;
    Ok(bytes)
}

/// The quality [`encode_jpeg`] writes photographs at (the report page's too): below 90,
/// `jpeg-encoder` halves the colour's resolution both ways (4:2:0, as cameras do), which
/// makes the encoding about twice as fast; lines drawn on a photo keep their brightness at full
/// resolution.
pub const JPEG_QUALITY: u8 = 85;

/// An RGB image as JPEG bytes at `quality` (1–100, by `jpeg-encoder`, which took half the time
/// of `image`'s encoder): the form for photographs and pictures drawn on them.
///
/// # Errors
/// [`EncodeError`] for an image wider or taller than JPEG's 65,535 pixels.
///
/// # Examples
/// ```
/// let image = image::RgbImage::from_pixel(4, 3, image::Rgb([200, 120, 40]));
/// let jpeg = splineface::io::encode_jpeg(&image, 90).unwrap();
/// assert!(jpeg.starts_with(&[0xFF, 0xD8, 0xFF]));
/// ```
pub fn encode_jpeg(image: &image::RgbImage, quality: u8) -> Result<Vec<u8>, EncodeError> {
    let too_large = || EncodeError::new("JPEG", "an image wider or taller than 65,535 pixels");
    let width = u16::try_from(image.width()).map_err(|_| too_large())?;
    let height = u16::try_from(image.height()).map_err(|_| too_large())?;
    let mut bytes = Vec::new();
    jpeg_encoder::Encoder::new(&mut bytes, quality)
        .encode(image.as_raw(), width, height, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| EncodeError::new("JPEG", e))?;
    Ok(bytes)
}

/// The FNV-1a 64-bit hash of `bytes`: the identity of an input file's bytes in fingerprints,
/// compact models and reference sources (fast and stable; not a cryptographic hash).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// [`fnv1a64`] as 16 lower-case hex digits (as
/// [`crate::reference::ReferenceSource::mesh_fnv1a64`] records it).
///
/// # Examples
/// ```
/// // The FNV-1a offset basis: the hash of nothing.
/// assert_eq!(splineface::io::fnv1a64_hex(b""), "cbf29ce484222325");
/// assert_eq!(splineface::io::fnv1a64_hex(b"a"), "af63dc4c8601ec8c");
/// ```
pub fn fnv1a64_hex(bytes: &[u8]) -> String {
    format!("{:016x}", fnv1a64(bytes))
}
