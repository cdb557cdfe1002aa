//! Writing faces out: the exact surface as STEP, meshes as textured OBJ (with MTL and PNG) and
//! binary glTF. Every file is written all or nothing ([`crate::io::write_atomically`]); a
//! writer that produces several files removes those it wrote if a later one fails.

mod glb;
mod step;

use std::path::{Path, PathBuf};

pub use glb::{PngTexture, encode_glb};
pub use step::{StepOptions, encode_step};

use crate::mesh::TriangleMesh;

/// The largest binary glTF file: its header counts bytes in 32 bits.
pub const MAX_GLB_BYTES: usize = u32::MAX as usize;

/// A file that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct ExportError {
    /// The file.
    pub file: PathBuf,
    /// What went wrong.
    pub problem: ExportProblem,
}

/// What went wrong writing a file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ExportProblem {
    /// An I/O error.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The content does not fit the format.
    #[error("too large for the format: {0}")]
    TooLarge(String),
    /// A path that cannot name the file (no file name, or not UTF-8 where a file must name
    /// another).
    #[error("{0}")]
    Path(String),
    /// The texture image could not be encoded.
    #[error("encoding the texture: {0}")]
    Image(String),
}

fn error(file: &Path, problem: impl Into<ExportProblem>) -> ExportError {
    ExportError {
        file: file.to_path_buf(),
        problem: problem.into(),
    }
}

/// Writes `bytes` to `path`, all or nothing.
///
/// # Errors
/// The I/O error, naming the file.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<(), ExportError> {
    crate::io::write_atomically(path, bytes).map_err(|e| error(path, e))
}

/// Writes a binary glTF file (see [`encode_glb`]).
///
/// # Errors
/// [`ExportProblem::TooLarge`] past 4 GiB, or the I/O error; nothing is left behind.
pub fn write_glb(
    path: &Path,
    mesh: &TriangleMesh,
    name: &str,
    texture: Option<PngTexture<'_>>,
) -> Result<(), ExportError> {
    let estimate =
        40 * mesh.positions().len() + 12 * mesh.triangles().len() + texture.map_or(0, |t| t.png.len());
    if estimate > MAX_GLB_BYTES {
        return Err(error(
            path,
            ExportProblem::TooLarge(format!("about {estimate} bytes")),
        ));
    }
    let bytes = encode_glb(mesh, name, texture);
    if bytes.len() > MAX_GLB_BYTES {
        return Err(error(
            path,
            ExportProblem::TooLarge(format!("{} bytes", bytes.len())),
        ));
    }
    write_file(path, &bytes)
}

/// Writes a textured OBJ: `path` (the mesh, which must have texture coordinates to be
/// textured), its material library beside it (`path` with extension `.mtl`) and the texture
/// (`.png`), naming each other by file name so the three can move together. Without texture
/// coordinates or texture, writes the OBJ alone.
///
/// # Errors
/// The first file that could not be written; files this call wrote are removed again.
pub fn write_obj(path: &Path, mesh: &TriangleMesh, texture: Option<&[u8]>) -> Result<(), ExportError> {
    let texture = texture.filter(|_| mesh.texture().is_some());
    let Some(png) = texture else {
        return write_file(path, crate::mesh::format_obj(mesh).as_bytes());
    };
    let stem = path.file_stem().and_then(|s| s.to_str()).ok_or_else(|| {
        error(
            path,
            ExportProblem::Path("the file name is not UTF-8 text".into()),
        )
    })?;
    let (mtl, image) = (path.with_extension("mtl"), path.with_extension("png"));
    let material = format!(
        "# written by splineface\nnewmtl face\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {stem}.png\n"
    );
    let obj = crate::mesh::format_obj_with_material(mesh, Some((&format!("{stem}.mtl"), "face")));
    crate::io::write_files_atomically(&[
        (image, png.to_vec()),
        (mtl, material.into_bytes()),
        (path.to_path_buf(), obj.into_bytes()),
    ])
    .map_err(|(file, e)| error(&file, e))
}
