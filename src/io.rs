//! Reading input files within limits, and writing output files without leaving partial files
//! behind.

use std::io::{Read, Write};
use std::path::Path;

/// The largest landmark or settings file read: 64 MiB (a 68-point file is about 1 KB).
pub const MAX_SMALL_INPUT_BYTES: u64 = 64 << 20;

/// The largest surface, reference or model file read: 1 GiB (dlib's 68-point model is 99 MB,
/// the embedded reference 0.3 MB).
pub const MAX_DATA_INPUT_BYTES: u64 = 1 << 30;

/// The largest mesh or photo file read: 4 GiB.
pub const MAX_LARGE_INPUT_BYTES: u64 = 4 << 30;

/// Reads an input file whole, if it is a regular file of at most `limit` bytes.
///
/// `std::fs::read` would read a device such as `/dev/zero` or a named pipe until memory runs
/// out or forever, and a directory gives a terse OS error; these are refused up front, with an
/// error saying what the path is. The size is checked before reading and the read is capped at
/// it, so a file that grows meanwhile cannot exceed the limit either.
///
/// # Errors
/// `NotFound` and other OS errors as they come; `InvalidInput` for a directory, a special file
/// or an oversized file.
pub fn read_input(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let refuse = |message: String| Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, message));
    let file = std::fs::File::open(path)?;
    let metadata = file.metadata()?;
    if metadata.is_dir() {
        return refuse("it is a directory, not a file".to_owned());
    }
    if !metadata.is_file() {
        return refuse("it is not a regular file (a device, pipe or socket)".to_owned());
    }
    if metadata.len() > limit {
        return refuse(format!(
            "it is {} bytes, more than the {} this input may have",
            metadata.len(),
            limit
        ));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(metadata.len()).unwrap_or(0));
    file.take(limit.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return refuse(format!("it grew past {limit} bytes while being read"));
    }
    Ok(bytes)
}

/// [`read_input`] for text: the bytes must be UTF-8 (a leading byte-order mark is dropped).
///
/// # Errors
/// As [`read_input`], and `InvalidData` naming the first byte that is not UTF-8 (UTF-16 files
/// from some Windows tools are recognised and named as such).
pub fn read_input_text(path: &Path, limit: u64) -> std::io::Result<String> {
    let bytes = read_input(path, limit)?;
    let bytes = bytes
        .strip_prefix(b"\xef\xbb\xbf")
        .map_or(bytes.as_slice(), |b| b);
    let invalid = |message: String| std::io::Error::new(std::io::ErrorKind::InvalidData, message);
    if bytes.starts_with(b"\xff\xfe") || bytes.starts_with(b"\xfe\xff") {
        return Err(invalid("the text is UTF-16; save it as UTF-8".to_owned()));
    }
    std::str::from_utf8(bytes)
        .map(str::to_owned)
        .map_err(|e| invalid(format!("the file is not UTF-8 text (byte {})", e.valid_up_to())))
}

/// Writes `bytes` to `path` all or nothing: the bytes go to a temporary file in the same
/// directory, which is flushed to disk and then renamed over `path`. If anything fails, the
/// temporary file is removed and `path` is untouched.
///
/// # Errors
/// The I/O error, with the path it concerns.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            format!("{} is not a file path", path.display()),
        )
    })?;
    let directory = match path.parent() {
        Some(parent) if !parent.as_os_str().is_empty() => parent,
        _ => Path::new("."),
    };
    let mut temporary_name = std::ffi::OsString::from(".");
    temporary_name.push(name);
    temporary_name.push(format!(".{}.tmp", std::process::id()));
    let temporary = directory.join(temporary_name);
    let result = (|| {
        let mut file = std::fs::File::create(&temporary)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result
}

/// Writes several files, each all or nothing ([`write_atomically`]), in order; if one fails,
/// those already written by this call are removed, so a failed call leaves none of them (it
/// does not restore files they replaced).
///
/// # Errors
/// The path that failed and its I/O error.
pub fn write_files_atomically(
    files: &[(std::path::PathBuf, Vec<u8>)],
) -> Result<(), (std::path::PathBuf, std::io::Error)> {
    for (k, (path, bytes)) in files.iter().enumerate() {
        if let Err(e) = write_atomically(path, bytes) {
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(done);
            }
            return Err((path.clone(), e));
        }
    }
    Ok(())
}
