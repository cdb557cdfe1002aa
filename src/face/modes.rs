//! Face-space modes from files: per-vertex displacement fields of one scan (`fit-reference
//! --identity-modes`), the form in which a morphable model's modes are usually shipped.
//!
//! A displacement file holds `modes × vertices × 3` little-endian `f32`, mode after mode,
//! vertex after vertex, `x y z`, in the scan's own frame and units; an expression names file
//! holds one name a line (blank lines and `#` comments skipped), one per expression mode.

use std::path::{Path, PathBuf};

use nalgebra::{Similarity3, Vector3};

use super::FaceSpace;
use crate::Real;
use crate::landmarks::read_vertex_indices;
use crate::reference::{ReferenceFace, ReferenceScan};
use crate::structure::{IBUG_POINT_COUNT, unify};

/// A mode file that cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct ModeFileError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong.
    pub problem: ModeFileProblem,
}

/// What is wrong with a mode file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModeFileProblem {
    /// It cannot be read.
    #[error("cannot read it: {0}")]
    Io(#[from] std::io::Error),
    /// Its length is not a whole number of modes.
    #[error(
        "{bytes} bytes is not a whole number of modes of {vertices} vertices × 3 float32 ({} bytes each)",
        vertices * 12
    )]
    Length {
        /// The file's length.
        bytes: usize,
        /// The scan's vertices.
        vertices: usize,
    },
    /// A displacement is NaN or infinite.
    #[error("mode {mode}, vertex {vertex}: the displacement is not finite")]
    NonFinite {
        /// The mode, from 0.
        mode: usize,
        /// The vertex, from 0.
        vertex: usize,
    },
    /// The expression names do not match the expression modes.
    #[error("{names} names for the {modes} expression modes of {}", fields.display())]
    Names {
        /// Names in the file.
        names: usize,
        /// Modes in the fields file.
        modes: usize,
        /// The fields file.
        fields: PathBuf,
    },
    /// The modes do not make a face space on the reference.
    #[error("{error}")]
    Space {
        /// Why.
        error: super::FaceError,
    },
    /// The scan's landmarks are a JSON file, not vertex indices the modes can move.
    #[error(
        "the face space's modes need the landmarks as 68 vertex indices (to move them with the modes), not a JSON landmark file"
    )]
    NotVertexIndices,
}

fn error(file: &Path, problem: impl Into<ModeFileProblem>) -> ModeFileError {
    ModeFileError {
        file: file.to_path_buf(),
        problem: problem.into(),
    }
}

/// `fit-reference`'s face-space inputs: displacement fields of one scan (the form is in the
/// module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct ModeFiles {
    /// The identity modes' fields.
    pub identity: PathBuf,
    /// The expression modes' fields and their names, if any.
    pub expressions: Option<(PathBuf, PathBuf)>,
    /// Where the modes came from, stored in the reference.
    pub note: String,
}

/// Displacement fields `[mode][vertex]` of a scan of `vertices` vertices (the form is in the
/// module docs), mapped into the canonical frame by `to_canonical` (its rotation and scale).
///
/// # Errors
/// A [`ModeFileError`] naming the file: unreadable, a length that is not a whole number of
/// modes, or a value that is not finite.
pub fn read_displacement_fields(
    path: &Path,
    vertices: usize,
    to_canonical: &Similarity3<Real>,
) -> Result<Vec<Vec<Vector3<Real>>>, ModeFileError> {
    let bytes = crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES).map_err(|e| error(path, e))?;
    let per_mode = vertices * 12;
    if bytes.is_empty() || per_mode == 0 || bytes.len() % per_mode != 0 {
        return Err(error(
            path,
            ModeFileProblem::Length {
                bytes: bytes.len(),
                vertices,
            },
        ));
    }
    let mut fields = Vec::with_capacity(bytes.len() / per_mode);
    for (mode, chunk) in bytes.chunks_exact(per_mode).enumerate() {
        let mut field = Vec::with_capacity(vertices);
        for (vertex, d) in chunk.chunks_exact(12).enumerate() {
            let c = |i: usize| Real::from(f32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]]));
            let vector = Vector3::new(c(0), c(4), c(8));
            if !vector.iter().all(|x| x.is_finite()) {
                return Err(error(path, ModeFileProblem::NonFinite { mode, vertex }));
            }
            field.push(to_canonical * vector);
        }
        fields.push(field);
    }
    Ok(fields)
}

impl ModeFiles {
    /// `reference` with a face space built from these fields of `scan`, whose 68 landmark
    /// vertices are listed in `landmarks` (a vertex-index file: the modes move those vertices
    /// and with them the structure). Identity modes get a prior deviation of 1 each.
    ///
    /// # Errors
    /// [`crate::Error::ModeFile`] for a file that cannot be used or whose modes do not make a
    /// space, [`crate::Error::Landmarks`] for the landmark file, [`crate::Error::Structure`] for
    /// the scan's structure, [`crate::Error::Reference`] when the reference refuses the space.
    pub fn build(
        &self,
        reference: ReferenceFace,
        scan: &ReferenceScan,
        landmarks: &Path,
    ) -> Result<ReferenceFace, crate::Error> {
        let mesh = &scan.mesh;
        let vertices = mesh.positions().len();
        if landmarks
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            return Err(error(landmarks, ModeFileProblem::NotVertexIndices).into());
        }
        // The indices again (the structure was read from them): the modes move those vertices.
        let indices = read_vertex_indices(landmarks, IBUG_POINT_COUNT, vertices)?;
        let (to_canonical, _) = unify(&scan.structure)?;
        let canonical = mesh.transformed(&nalgebra::convert(to_canonical));
        let identity = read_displacement_fields(&self.identity, vertices, &to_canonical)?;
        let sigma = vec![1.0; identity.len()];
        let mut space = FaceSpace::from_displacements(&reference, &canonical, &indices, &identity, &sigma)
            .map_err(|error| self::error(&self.identity, ModeFileProblem::Space { error }))?;
        if let Some((fields_path, names_path)) = &self.expressions {
            let fields = read_displacement_fields(fields_path, vertices, &to_canonical)?;
            let text = crate::io::read_input_text(names_path, crate::io::MAX_DATA_INPUT_BYTES)
                .map_err(|e| error(names_path, e))?;
            let names: Vec<String> = text
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(str::to_owned)
                .collect();
            if names.len() != fields.len() {
                return Err(error(
                    names_path,
                    ModeFileProblem::Names {
                        names: names.len(),
                        modes: fields.len(),
                        fields: fields_path.clone(),
                    },
                )
                .into());
            }
            space = space
                .with_expression_displacements(&reference, &canonical, &indices, &names, &fields, &self.note)
                .map_err(|error| self::error(fields_path, ModeFileProblem::Space { error }))?;
        }
        Ok(reference.with_space(Some(space.to_modes(&self.note)))?)
    }
}
