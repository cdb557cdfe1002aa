//! Triangle meshes and their files: OBJ, PLY (ASCII and binary) and glTF/GLB in; OBJ and PLY
//! out.
//!
//! A [`TriangleMesh`] keeps its vertices **in file order**, because landmark files name scan
//! vertices by their index in the file (see [`crate::landmarks::read_vertex_indices`]).
//! Polygons are fan-triangulated. Texture coordinates are kept as their own indexed array
//! ([`TextureCoordinates`]), one index triple per triangle, as OBJ stores them, so that a
//! vertex on a texture seam needs no duplicating.
//!
//! Every reader validates what it reads and reports the first problem with the file's name and
//! where in it (line, element or accessor), never panicking. Writers write all or nothing
//! ([`crate::io::write_atomically`]).
//!
//! Why not `tobj` for OBJ: it renumbers vertices by their first use in faces, which breaks
//! vertex-index landmarks. The test suite checks this reader against `tobj` on geometry.

use std::path::{Path, PathBuf};

use nalgebra::{Affine3, Point2, Point3, Vector3};

use crate::Real;

mod closest;
mod glb;
mod gltf;
mod obj;
mod ply;
mod raster;

pub(crate) use closest::in_morton_order;
pub use closest::{Closest, ClosestPoints, closest_on_triangle};
pub use glb::{MAX_GLB_BYTES, PngTexture, encode_glb, write_glb};
pub use gltf::parse_gltf;
pub(crate) use obj::format_obj_with_material;
pub use obj::{format_mtl, format_obj, parse_obj, write_obj};
pub use ply::{PlyEncoding, encode_ply, parse_ply, parse_ply_points};
pub use raster::{FrontHit, Raster, front_heights, front_hits};

/// Texture coordinates of a mesh (`v` up, as in OBJ and PLY; glTF's are flipped on reading):
/// a `uv` array and, for each triangle of the mesh, the indices
/// of its three corners' coordinates in it.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureCoordinates {
    /// The coordinates.
    pub uvs: Vec<Point2<Real>>,
    /// One triple per triangle of the mesh, indexing `uvs`.
    pub triangles: Vec<[u32; 3]>,
}

/// A triangle mesh: vertex positions in file order, triangles as index triples, and optional
/// texture coordinates.
///
/// Invariants (checked by [`TriangleMesh::new`] and [`TriangleMesh::with_texture`]): every
/// coordinate is finite, every index is in range, there are as many texture triangles as
/// triangles.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleMesh {
    positions: Vec<Point3<Real>>,
    triangles: Vec<[u32; 3]>,
    texture: Option<TextureCoordinates>,
    normals: Option<Vec<Vector3<Real>>>,
}

/// A mesh file that could not be read or written.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct MeshError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong.
    pub problem: MeshProblem,
}

/// What is wrong with a mesh or a mesh file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MeshProblem {
    /// The file could not be read or written.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// The file's extension names no format this crate reads or writes.
    #[error("unknown mesh format (expected .obj, .ply, .gltf or .glb; writing: .obj or .ply)")]
    UnknownFormat,
    /// A line or a header field is malformed.
    #[error("{location}: {message}")]
    Syntax {
        /// Where: `line 12`, `vertex 7`, `accessor 3`, …
        location: String,
        /// What was expected.
        message: String,
    },
    /// A coordinate is NaN or infinite.
    #[error("{location}: a coordinate is not finite")]
    NonFinite {
        /// Where.
        location: String,
    },
    /// An index refers past the end of what it indexes.
    #[error("{location}: index {index} is out of range ({count} {what})")]
    IndexOutOfRange {
        /// Where.
        location: String,
        /// The index.
        index: i64,
        /// How many there are.
        count: usize,
        /// Of what: `vertices`, `texture coordinates`.
        what: &'static str,
    },
    /// The file ends before the data it announces.
    #[error("the file is truncated: {0}")]
    Truncated(String),
    /// The file holds no triangle.
    #[error("no triangles")]
    Empty,
    /// More vertices or triangles than a `u32` index can address.
    #[error("too large: {0}")]
    TooLarge(String),
    /// A valid file using something this reader does not support.
    #[error("unsupported: {0}")]
    Unsupported(String),
}

pub(crate) fn syntax(location: impl Into<String>, message: impl Into<String>) -> MeshProblem {
    MeshProblem::Syntax {
        location: location.into(),
        message: message.into(),
    }
}

impl TriangleMesh {
    /// A mesh without texture coordinates.
    ///
    /// # Errors
    /// [`MeshProblem::Empty`] without triangles, [`MeshProblem::NonFinite`] for a NaN or
    /// infinite coordinate, [`MeshProblem::IndexOutOfRange`] for a bad index.
    pub fn new(positions: Vec<Point3<Real>>, triangles: Vec<[u32; 3]>) -> Result<Self, MeshProblem> {
        if triangles.is_empty() {
            return Err(MeshProblem::Empty);
        }
        if u32::try_from(positions.len()).is_err() {
            return Err(MeshProblem::TooLarge(format!("{} vertices", positions.len())));
        }
        if let Some(k) = positions.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(MeshProblem::NonFinite {
                location: format!("vertex {k}"),
            });
        }
        check_indices(&triangles, positions.len(), "vertices")?;
        Ok(Self {
            positions,
            triangles,
            texture: None,
            normals: None,
        })
    }

    /// This mesh with texture coordinates (replacing any it had).
    ///
    /// # Errors
    /// [`MeshProblem::Syntax`] if the texture has another number of triangles than the mesh,
    /// [`MeshProblem::NonFinite`] or [`MeshProblem::IndexOutOfRange`] as for positions.
    pub fn with_texture(mut self, texture: TextureCoordinates) -> Result<Self, MeshProblem> {
        if texture.triangles.len() != self.triangles.len() {
            return Err(syntax(
                "texture coordinates",
                format!(
                    "{} texture triangles for {} triangles",
                    texture.triangles.len(),
                    self.triangles.len()
                ),
            ));
        }
        if let Some(k) = texture.uvs.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(MeshProblem::NonFinite {
                location: format!("texture coordinate {k}"),
            });
        }
        check_indices(&texture.triangles, texture.uvs.len(), "texture coordinates")?;
        self.texture = Some(texture);
        Ok(self)
    }

    /// This mesh with one unit normal per vertex (replacing any it had). Writers store them
    /// (OBJ `vn`, PLY `nx ny nz`, glTF `NORMAL`); readers do not read them back.
    ///
    /// # Errors
    /// [`MeshProblem::Syntax`] for another count than the vertices', [`MeshProblem::NonFinite`]
    /// for a normal that is not finite and of unit length (to 10⁻⁶).
    pub fn with_normals(mut self, normals: Vec<Vector3<Real>>) -> Result<Self, MeshProblem> {
        if normals.len() != self.positions.len() {
            return Err(syntax(
                "normals",
                format!("{} normals for {} vertices", normals.len(), self.positions.len()),
            ));
        }
        if let Some(k) = normals.iter().position(|n| {
            !matches!(
                (n.norm() - 1.0).abs().partial_cmp(&1e-6),
                Some(std::cmp::Ordering::Less)
            )
        }) {
            return Err(MeshProblem::NonFinite {
                location: format!("normal {k}"),
            });
        }
        self.normals = Some(normals);
        Ok(self)
    }

    /// The per-vertex unit normals, if the mesh has them.
    pub fn normals(&self) -> Option<&[Vector3<Real>]> {
        self.normals.as_deref()
    }

    /// The vertex positions, in file order.
    pub fn positions(&self) -> &[Point3<Real>] {
        &self.positions
    }

    /// The triangles, as indices into [`TriangleMesh::positions`], counter-clockwise seen from
    /// the front as the source file had them.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The texture coordinates, if the source had them for every triangle.
    pub fn texture(&self) -> Option<&TextureCoordinates> {
        self.texture.as_ref()
    }

    /// The mesh with every position mapped by `transform` (texture coordinates unchanged;
    /// normals mapped by the inverse transpose and renormalised, and dropped if `transform` is
    /// singular).
    pub fn transformed(&self, transform: &Affine3<Real>) -> Self {
        let linear = transform.matrix().fixed_view::<3, 3>(0, 0).into_owned();
        let cofactor = linear.try_inverse().map(|inverse| inverse.transpose());
        let normals = match (&self.normals, cofactor) {
            (Some(normals), Some(cofactor)) => {
                let mapped: Option<Vec<Vector3<Real>>> = normals
                    .iter()
                    .map(|n| (cofactor * n).try_normalize(0.0))
                    .collect();
                mapped
            }
            _ => None,
        };
        Self {
            positions: self.positions.iter().map(|p| transform * p).collect(),
            triangles: self.triangles.clone(),
            texture: self.texture.clone(),
            normals,
        }
    }

    /// The positions of triangle `k`'s corners.
    pub fn triangle(&self, k: usize) -> [Point3<Real>; 3] {
        self.triangles[k].map(|i| self.positions[i as usize])
    }
}

fn check_indices(triangles: &[[u32; 3]], count: usize, what: &'static str) -> Result<(), MeshProblem> {
    for (k, t) in triangles.iter().enumerate() {
        if let Some(&index) = t.iter().find(|&&i| i as usize >= count) {
            return Err(MeshProblem::IndexOutOfRange {
                location: format!("triangle {k}"),
                index: index.into(),
                count,
                what,
            });
        }
    }
    Ok(())
}

/// A mesh file format, chosen by file extension (case-insensitive).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// Stanford PLY (`.ply`), ASCII or binary.
    Ply,
    /// glTF 2.0 (`.gltf` with its buffers, or binary `.glb`); read only.
    Gltf,
}

impl MeshFormat {
    /// The format a path's extension names, if any.
    pub fn from_path(path: &Path) -> Option<Self> {
        let extension = path.extension()?.to_str()?.to_ascii_lowercase();
        match extension.as_str() {
            "obj" => Some(Self::Obj),
            "ply" => Some(Self::Ply),
            "gltf" | "glb" => Some(Self::Gltf),
            _ => None,
        }
    }
}

/// Reads a mesh, choosing the reader by the file's extension.
///
/// For glTF, the meshes of the default scene (or of the first scene, or every mesh when the
/// file has no scene) are placed by their nodes' transforms and concatenated in traversal
/// order; vertex indices count through the primitives in that order.
///
/// # Errors
/// A [`MeshError`] naming the file and the first problem.
///
/// # Examples
/// ```
/// use splineface::mesh::read_mesh;
///
/// let path = std::env::temp_dir().join(format!("read-mesh-example-{}.obj", std::process::id()));
/// std::fs::write(&path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
/// let mesh = read_mesh(&path).unwrap();
/// assert_eq!((mesh.positions().len(), mesh.triangles(), mesh.positions()[1].x), (3, &[[0, 1, 2]][..], 1.0));
///
/// // An error names the file and the problem.
/// std::fs::write(&path, "v 0 0 nan\n").unwrap();
/// let error = read_mesh(&path).unwrap_err();
/// assert_eq!(error.file, path);
/// assert!(error.to_string().contains("not finite"), "{error}");
/// # std::fs::remove_file(&path).unwrap();
/// ```
pub fn read_mesh(path: &Path) -> Result<TriangleMesh, MeshError> {
    let error = |problem| MeshError {
        file: path.to_path_buf(),
        problem,
    };
    match MeshFormat::from_path(path) {
        None => Err(error(MeshProblem::UnknownFormat)),
        Some(MeshFormat::Obj) => {
            let bytes =
                crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES).map_err(|e| error(e.into()))?;
            let text = crate::io::utf8_text(&bytes).map_err(|message| error(syntax("OBJ", message)))?;
            parse_obj(text).map_err(error)
        }
        Some(MeshFormat::Ply) => {
            let bytes =
                crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES).map_err(|e| error(e.into()))?;
            parse_ply(&bytes).map_err(error)
        }
        Some(MeshFormat::Gltf) => gltf::read_gltf(path).map_err(error),
    }
}

/// Writes a mesh as OBJ or PLY (binary little-endian, `f64` coordinates), choosing by the
/// file's extension; all or nothing. Both forms read back exactly.
///
/// # Errors
/// A [`MeshError`] naming the file: an extension other than `.obj` or `.ply`, or an I/O error.
pub fn write_mesh(path: &Path, mesh: &TriangleMesh) -> Result<(), MeshError> {
    let error = |problem| MeshError {
        file: path.to_path_buf(),
        problem,
    };
    let bytes = encode_mesh(path, mesh).ok_or_else(|| error(MeshProblem::UnknownFormat))?;
    crate::io::write_atomically(path, &bytes).map_err(|e| error(e.into()))
}

/// The bytes [`write_mesh`] writes to `path`: OBJ or binary PLY by its extension; `None` for
/// any other.
pub fn encode_mesh(path: &Path, mesh: &TriangleMesh) -> Option<Vec<u8>> {
    match MeshFormat::from_path(path)? {
        MeshFormat::Obj => Some(format_obj(mesh).into_bytes()),
        MeshFormat::Ply => Some(encode_ply(mesh, PlyEncoding::BinaryLittleEndian)),
        MeshFormat::Gltf => None,
    }
}
