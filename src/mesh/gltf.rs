//! glTF 2.0 (`.gltf` with external or embedded buffers, and binary `.glb`), read only.

use std::path::Path;

use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use nalgebra::{Matrix4, Point2, Point3};

use super::{MeshProblem, TextureCoordinates, TriangleMesh, syntax};
use crate::Real;

/// Reads the triangles of a glTF file's scene (see [`super::read_mesh`]).
pub(super) fn read_gltf(path: &Path) -> Result<TriangleMesh, MeshProblem> {
    let bytes = crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES)?;
    parse_gltf(&bytes, Some(path.parent().unwrap_or(Path::new("."))))
}

/// Parses a glTF 2.0 file's bytes, text `.gltf` or binary `.glb` (see [`super::read_mesh`] for
/// what is read).
///
/// Buffers come from the GLB's binary chunk, from `data:` URIs, or from files named by
/// relative (or `file:`) URIs, resolved against `base`. Only regular files are read, and only
/// the buffer's declared length of them, so a URI naming a device or a pipe is an error, not a
/// hang. With `base` = `None`, a buffer in another file is an error. No other URI scheme is
/// fetched.
///
/// # Errors
/// The first problem found: malformed JSON or GLB framing, lengths the file does not hold,
/// missing or unreadable buffers, unsupported primitives, indices out of range, non-finite
/// coordinates.
pub fn parse_gltf(bytes: &[u8], base: Option<&Path>) -> Result<TriangleMesh, MeshProblem> {
    check_glb_header(bytes)?;
    check_position_accessors(bytes)?;
    // The `gltf` crate (1.4) can panic on inconsistent files: fuzzing found an index out of
    // bounds in its own validation (gltf-json mesh.rs:151, a POSITION attribute naming a
    // missing accessor, which `check_position_accessors` now refuses first). Any other panic
    // there is this file's problem, not the program's, so it becomes an error.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| build_mesh(bytes, base))).unwrap_or_else(|_| {
        Err(syntax(
            "glTF",
            "the file's references are inconsistent (the gltf crate failed validating it)",
        ))
    })
}

fn build_mesh(bytes: &[u8], base: Option<&Path>) -> Result<TriangleMesh, MeshProblem> {
    let gltf = gltf::Gltf::from_slice(bytes).map_err(gltf_problem)?;
    let document = &gltf.document;
    let buffers = document
        .buffers()
        .map(|buffer| load_buffer(&buffer, gltf.blob.as_deref(), base))
        .collect::<Result<Vec<_>, _>>()?;
    let mut builder = Builder::default();
    let scene = document.default_scene().or_else(|| document.scenes().next());
    match scene {
        Some(scene) => {
            for node in scene.nodes() {
                builder.node(&node, &Matrix4::identity(), &buffers, 0, document.nodes().len())?;
            }
        }
        None => {
            for mesh in document.meshes() {
                builder.mesh(&mesh, &Matrix4::identity(), &buffers)?;
            }
        }
    }
    builder.finish()
}

/// One buffer's bytes, exactly its declared length (longer sources are cut, shorter ones are
/// errors). This replaces `gltf::import_buffers`, which reads whatever file a URI names to its
/// end (a `file:///dev/zero` buffer never returns) and allocates before checking lengths.
fn load_buffer(
    buffer: &gltf::Buffer,
    blob: Option<&[u8]>,
    base: Option<&Path>,
) -> Result<Vec<u8>, MeshProblem> {
    let location = || format!("buffer {}", buffer.index());
    let length = buffer.length();
    let short = |have: usize| {
        MeshProblem::Truncated(format!(
            "{}: {length} bytes declared, its source holds {have}",
            location()
        ))
    };
    let data = match buffer.source() {
        gltf::buffer::Source::Bin => {
            let blob =
                blob.ok_or_else(|| syntax(location(), "refers to a binary chunk the file does not have"))?;
            blob.get(..length).ok_or_else(|| short(blob.len()))?.to_vec()
        }
        gltf::buffer::Source::Uri(uri) => {
            if let Some(rest) = uri.strip_prefix("data:") {
                let (_, payload) = rest.split_once(";base64,").ok_or_else(|| {
                    MeshProblem::Unsupported(format!("{}: a data URI that is not base64", location()))
                })?;
                let mut data = base64::decode(payload)
                    .map_err(|e| syntax(location(), format!("the data URI is not valid base64 ({e})")))?;
                if data.len() < length {
                    return Err(short(data.len()));
                }
                data.truncate(length);
                data
            } else {
                let name = external_path(uri).ok_or_else(|| {
                    MeshProblem::Unsupported(format!(
                        "{}: the URI {uri:?} (only files and data: URIs are read)",
                        location()
                    ))
                })?;
                let base = base.ok_or_else(|| {
                    syntax(
                        location(),
                        format!("lives in another file ({name}), which is not available here"),
                    )
                })?;
                let path = base.join(&name);
                let io = |e: std::io::Error| {
                    MeshProblem::Io(std::io::Error::new(
                        e.kind(),
                        format!("{}: {}: {e}", location(), path.display()),
                    ))
                };
                // Looked at before opening: opening a named pipe blocks until someone writes.
                if !std::fs::metadata(&path).map_err(io)?.is_file() {
                    return Err(syntax(
                        location(),
                        format!("{} is not a regular file", path.display()),
                    ));
                }
                let file = std::fs::File::open(&path).map_err(io)?;
                let metadata = file.metadata().map_err(io)?;
                if !metadata.is_file() {
                    return Err(syntax(
                        location(),
                        format!("{} is not a regular file", path.display()),
                    ));
                }
                let have = usize::try_from(metadata.len()).unwrap_or(usize::MAX);
                if have < length {
                    return Err(short(have));
                }
                let mut data = Vec::with_capacity(length);
                std::io::Read::read_to_end(&mut std::io::Read::take(file, length as u64), &mut data)
                    .map_err(io)?;
                if data.len() < length {
                    return Err(short(data.len()));
                }
                data
            }
        }
    };
    Ok(data)
}

/// The file path a buffer URI names, percent-decoded: a relative reference or a `file:` URI;
/// `None` for any other scheme or a malformed escape.
fn external_path(uri: &str) -> Option<String> {
    let path = if let Some(rest) = uri.strip_prefix("file://") {
        rest
    } else if let Some(rest) = uri.strip_prefix("file:") {
        rest
    } else {
        // A colon before the first slash starts a scheme (RFC 3986 §4.2).
        let first_slash = uri.find('/').unwrap_or(uri.len());
        if uri[..first_slash].contains(':') {
            return None;
        }
        uri
    };
    let bytes = path.as_bytes();
    let mut decoded = Vec::with_capacity(bytes.len());
    let mut k = 0;
    while k < bytes.len() {
        if bytes[k] == b'%' {
            let hex = std::str::from_utf8(bytes.get(k + 1..k + 3)?).ok()?;
            decoded.push(u8::from_str_radix(hex, 16).ok()?);
            k += 3;
        } else {
            decoded.push(bytes[k]);
            k += 1;
        }
    }
    String::from_utf8(decoded).ok().filter(|p| !p.is_empty())
}

/// Checks a binary glTF's header and chunk lengths against the file's size before the `gltf`
/// crate sees it: it allocates what the header claims (a fuzzed 20-byte file claiming 3 GB ran
/// out of memory), so lies about lengths are refused here. Text glTF passes through.
fn check_glb_header(bytes: &[u8]) -> Result<(), MeshProblem> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let word = |at: usize| -> Option<usize> {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let truncated = |what: &str| MeshProblem::Truncated(format!("binary glTF: {what}"));
    let total = word(8).ok_or_else(|| truncated("no header"))?;
    if total != bytes.len() {
        return Err(truncated(&format!(
            "the header says {total} bytes, the file has {}",
            bytes.len()
        )));
    }
    let mut at = 12;
    while at < bytes.len() {
        let length = word(at).ok_or_else(|| truncated("a chunk header is cut"))?;
        if length > bytes.len() - at - 8.min(bytes.len() - at) {
            return Err(truncated(&format!(
                "a chunk claims {length} bytes, more than the file holds"
            )));
        }
        at += 8 + length;
    }
    Ok(())
}

/// Refuses a primitive whose `POSITION` attribute names an accessor the file does not have,
/// before the `gltf` crate's validation indexes the accessors with it and panics (gltf-json
/// 1.4.1 mesh.rs:151; three fuzzed files found it). The JSON is read into just the fields
/// involved, the way the `gltf` crate reads it: unknown fields are skipped unchecked (a first
/// version parsed a `serde_json::Value`, which refuses invalid UTF-8 in a key the gltf crate
/// skips, and so let a fuzzed file through). JSON the `gltf` crate will refuse anyway passes
/// through, for it to report.
fn check_position_accessors(bytes: &[u8]) -> Result<(), MeshProblem> {
    use serde::de::IgnoredAny;
    #[derive(serde::Deserialize)]
    struct Document {
        #[serde(default)]
        accessors: Vec<IgnoredAny>,
        #[serde(default)]
        meshes: Vec<Mesh>,
    }
    #[derive(serde::Deserialize)]
    struct Mesh {
        #[serde(default)]
        primitives: Vec<Primitive>,
    }
    #[derive(serde::Deserialize)]
    struct Primitive {
        // A map, as the gltf crate reads it: a repeated key keeps its last value.
        #[serde(default)]
        attributes: std::collections::BTreeMap<String, serde_json::Value>,
    }
    let json = if bytes.starts_with(b"glTF") {
        // `check_glb_header` has checked the chunk lengths.
        let length = bytes
            .get(12..16)
            .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
        bytes.get(20..20 + length).unwrap_or_default()
    } else {
        bytes
    };
    let Ok(document) = serde_json::from_slice::<Document>(json) else {
        return Ok(());
    };
    let accessors = document.accessors.len();
    for (m, mesh) in document.meshes.iter().enumerate() {
        for (p, primitive) in mesh.primitives.iter().enumerate() {
            if let Some(index) = primitive
                .attributes
                .get("POSITION")
                .and_then(serde_json::Value::as_u64)
                && index >= accessors as u64
            {
                return Err(syntax(
                    format!("mesh {m} primitive {p}"),
                    format!("POSITION names accessor {index}, and the file has {accessors}"),
                ));
            }
        }
    }
    Ok(())
}

fn gltf_problem(error: gltf::Error) -> MeshProblem {
    match error {
        gltf::Error::Io(e) => MeshProblem::Io(e),
        other => syntax("glTF", other.to_string()),
    }
}

#[derive(Default)]
struct Builder {
    positions: Vec<Point3<Real>>,
    triangles: Vec<[u32; 3]>,
    uvs: Vec<Point2<Real>>,
    /// Whether every primitive so far had texture coordinates.
    textured: bool,
    primitives: usize,
}

/// Checks that an accessor can be read as `dimensions` of one of `types`: present, dense,
/// non-empty, in a buffer view. The `gltf` reader itself bounds-checks the view against its
/// buffer; these are the cases where it would panic or misread instead.
fn check_accessor(
    accessor: &gltf::Accessor,
    dimensions: Dimensions,
    types: &[DataType],
    what: &str,
) -> Result<(), MeshProblem> {
    let location = || format!("accessor {} ({what})", accessor.index());
    if accessor.sparse().is_some() {
        return Err(MeshProblem::Unsupported(format!(
            "{}: sparse accessors",
            location()
        )));
    }
    if accessor.view().is_none() {
        return Err(syntax(location(), "no buffer view"));
    }
    if accessor.count() == 0 {
        return Err(syntax(location(), "no elements"));
    }
    if accessor.dimensions() != dimensions || !types.contains(&accessor.data_type()) {
        return Err(syntax(
            location(),
            format!(
                "{:?} of {:?}, expected {dimensions:?} of one of {types:?}",
                accessor.dimensions(),
                accessor.data_type()
            ),
        ));
    }
    if let Some(stride) = accessor.view().and_then(|v| v.stride())
        && stride < accessor.size()
    {
        return Err(syntax(
            location(),
            format!("stride {stride} is below the element size"),
        ));
    }
    Ok(())
}

impl Builder {
    fn node(
        &mut self,
        node: &gltf::Node,
        parent: &Matrix4<Real>,
        buffers: &[Vec<u8>],
        depth: usize,
        nodes: usize,
    ) -> Result<(), MeshProblem> {
        if depth > nodes {
            return Err(syntax(
                format!("node {}", node.index()),
                "the node hierarchy has a cycle",
            ));
        }
        let local = node.transform().matrix();
        let local = Matrix4::from_fn(|r, c| Real::from(local[c][r]));
        let world = parent * local;
        if let Some(mesh) = node.mesh() {
            self.mesh(&mesh, &world, buffers)?;
        }
        for child in node.children() {
            self.node(&child, &world, buffers, depth + 1, nodes)?;
        }
        Ok(())
    }

    fn mesh(
        &mut self,
        mesh: &gltf::Mesh,
        world: &Matrix4<Real>,
        buffers: &[Vec<u8>],
    ) -> Result<(), MeshProblem> {
        for primitive in mesh.primitives() {
            let location = || format!("mesh {} primitive {}", mesh.index(), primitive.index());
            let mode = primitive.mode();
            if !matches!(mode, Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan) {
                return Err(MeshProblem::Unsupported(format!(
                    "{}: {mode:?} primitives",
                    location()
                )));
            }
            let positions_accessor = primitive
                .get(&gltf::Semantic::Positions)
                .ok_or_else(|| syntax(location(), "no POSITION attribute"))?;
            check_accessor(
                &positions_accessor,
                Dimensions::Vec3,
                &[DataType::F32],
                "POSITION",
            )?;
            let reader = primitive.reader(|buffer| buffers.get(buffer.index()).map(|data| &data[..]));
            let truncated = |what: &str| {
                MeshProblem::Truncated(format!("{}: {what} lies outside its buffer", location()))
            };
            let offset = self.positions.len();
            let count = positions_accessor.count();
            for p in reader.read_positions().ok_or_else(|| truncated("POSITION"))? {
                let p = Point3::new(Real::from(p[0]), Real::from(p[1]), Real::from(p[2]));
                let q = world.transform_point(&p);
                if !q.iter().all(|c| c.is_finite()) {
                    return Err(MeshProblem::NonFinite {
                        location: format!("{} vertex {}", location(), self.positions.len() - offset),
                    });
                }
                self.positions.push(q);
            }
            let indices: Vec<u32> = match primitive.indices() {
                Some(accessor) => {
                    check_accessor(
                        &accessor,
                        Dimensions::Scalar,
                        &[DataType::U8, DataType::U16, DataType::U32],
                        "indices",
                    )?;
                    let indices = reader
                        .read_indices()
                        .ok_or_else(|| truncated("the index accessor"))?;
                    indices.into_u32().collect()
                }
                None => (0..u32::try_from(count).map_err(|_| MeshProblem::TooLarge(location()))?).collect(),
            };
            if let Some(&bad) = indices.iter().find(|&&i| i as usize >= count) {
                return Err(MeshProblem::IndexOutOfRange {
                    location: location(),
                    index: bad.into(),
                    count,
                    what: "vertices",
                });
            }
            let base = u32::try_from(offset).map_err(|_| MeshProblem::TooLarge(location()))?;
            let corners: Vec<[u32; 3]> = match mode {
                Mode::Triangles => {
                    if !indices.len().is_multiple_of(3) {
                        return Err(syntax(
                            location(),
                            format!("{} indices, not a multiple of 3", indices.len()),
                        ));
                    }
                    indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
                }
                // Every other strip triangle is flipped to keep a consistent orientation.
                Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                    .map(|k| {
                        let (a, b, c) = (indices[k], indices[k + 1], indices[k + 2]);
                        if k % 2 == 0 { [a, b, c] } else { [b, a, c] }
                    })
                    .collect(),
                _ => (1..indices.len().saturating_sub(1))
                    .map(|k| [indices[0], indices[k], indices[k + 1]])
                    .collect(),
            };
            self.triangles.extend(corners.iter().map(|t| t.map(|i| i + base)));
            let uvs = match primitive.get(&gltf::Semantic::TexCoords(0)) {
                Some(accessor) => {
                    check_accessor(
                        &accessor,
                        Dimensions::Vec2,
                        &[DataType::F32, DataType::U8, DataType::U16],
                        "TEXCOORD_0",
                    )?;
                    if accessor.count() != count {
                        return Err(syntax(location(), "TEXCOORD_0 and POSITION differ in count"));
                    }
                    let read = reader.read_tex_coords(0).ok_or_else(|| truncated("TEXCOORD_0"))?;
                    // glTF's v runs down the image, OBJ's and PLY's up: flip to the latter.
                    Some(
                        read.into_f32()
                            .map(|t| Point2::new(Real::from(t[0]), 1.0 - Real::from(t[1]))),
                    )
                }
                None => None,
            };
            self.textured = (self.primitives == 0 || self.textured) && uvs.is_some();
            if let Some(uvs) = uvs {
                self.uvs.extend(uvs);
            }
            self.primitives += 1;
        }
        Ok(())
    }

    fn finish(self) -> Result<TriangleMesh, MeshProblem> {
        let mesh = TriangleMesh::new(self.positions, self.triangles)?;
        if self.textured && self.uvs.len() == mesh.positions().len() {
            let triangles = mesh.triangles().to_vec();
            mesh.with_texture(TextureCoordinates {
                uvs: self.uvs,
                triangles,
            })
        } else {
            Ok(mesh)
        }
    }
}
