//! Writing output files without leaving partial files behind.

use std::io::Write;
use std::path::Path;

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
