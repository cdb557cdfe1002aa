//! Stanford PLY, ASCII and binary (either byte order).
//!
//! Read: the `vertex` element's `x`, `y`, `z` and texture coordinates (`u`/`v`, `s`/`t`,
//! `texture_u`/`texture_v` or `texture_s`/`texture_t`), the `face` element's index list
//! (`vertex_indices` or `vertex_index`) and its optional per-corner `texcoord` list (the
//! MeshLab convention). Every other element and property is read past.

use std::fmt::Write;

use nalgebra::{Point2, Point3};

use super::{MeshProblem, TextureCoordinates, TriangleMesh, syntax};
use crate::Real;

/// How [`encode_ply`] writes the body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyEncoding {
    /// Text, one element a line.
    Ascii,
    /// Little-endian binary.
    BinaryLittleEndian,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    fn is_integer(self) -> bool {
        !matches!(self, Self::F32 | Self::F64)
    }
}

#[derive(Debug)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Self::Scalar { name, .. } | Self::List { name, .. } => name,
        }
    }
}

#[derive(Debug)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Ascii,
    Binary { big_endian: bool },
}

/// The body being read: the numbers of an ASCII body, or the bytes of a binary one.
enum Body<'a> {
    Ascii(std::str::SplitAsciiWhitespace<'a>),
    Binary { bytes: &'a [u8], big_endian: bool },
}

impl Body<'_> {
    /// The next value of type `ty`, widened to `f64` (exact for every PLY type).
    fn read(&mut self, ty: Scalar, location: &dyn Fn() -> String) -> Result<f64, MeshProblem> {
        match self {
            Self::Ascii(tokens) => {
                let token = tokens
                    .next()
                    .ok_or_else(|| MeshProblem::Truncated(format!("{} is incomplete", location())))?;
                let value: f64 = if ty.is_integer() {
                    token
                        .parse::<i64>()
                        .map(|v| v as f64)
                        .map_err(|_| syntax(location(), format!("`{token}` is not an integer")))?
                } else {
                    token
                        .parse()
                        .map_err(|_| syntax(location(), format!("`{token}` is not a number")))?
                };
                Ok(value)
            }
            Self::Binary { bytes, big_endian } => {
                let size = ty.size();
                if bytes.len() < size {
                    return Err(MeshProblem::Truncated(format!("{} is incomplete", location())));
                }
                let (head, rest) = bytes.split_at(size);
                *bytes = rest;
                let mut buffer = [0u8; 8];
                buffer[..size].copy_from_slice(head);
                if *big_endian {
                    buffer[..size].reverse();
                }
                let b = buffer;
                Ok(match ty {
                    Scalar::I8 => f64::from(b[0] as i8),
                    Scalar::U8 => f64::from(b[0]),
                    Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
                    Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
                    Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                    Scalar::F64 => f64::from_le_bytes(b),
                })
            }
        }
    }

    fn is_exhausted(&mut self) -> bool {
        match self {
            Self::Ascii(tokens) => tokens.next().is_none(),
            Self::Binary { bytes, .. } => bytes.is_empty(),
        }
    }
}

/// Splits the header from the body and parses it.
fn header(bytes: &[u8]) -> Result<(Format, Vec<Element>, &[u8]), MeshProblem> {
    const END: &[u8] = b"end_header";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or_else(|| syntax("header", "no `end_header` line"))?;
    let newline = bytes[end..]
        .iter()
        .position(|&b| b == b'\n')
        .ok_or_else(|| MeshProblem::Truncated("nothing after `end_header`".into()))?;
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| syntax("header", "the header is not text"))?;
    let body = &bytes[end + newline + 1..];
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
    if lines.next().map(|(_, l)| l) != Some("ply") {
        return Err(syntax("line 1", "not a PLY file (no `ply` magic line)"));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (line, content) in lines {
        let location = || format!("header line {line}");
        let fields: Vec<&str> = content.split_whitespace().collect();
        match fields.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, version] => {
                if *version != "1.0" {
                    return Err(MeshProblem::Unsupported(format!("PLY version {version}")));
                }
                format = Some(match *kind {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::Binary { big_endian: false },
                    "binary_big_endian" => Format::Binary { big_endian: true },
                    other => return Err(syntax(location(), format!("unknown format `{other}`"))),
                });
            }
            ["element", name, count] => {
                let count: usize = count
                    .parse()
                    .map_err(|_| syntax(location(), format!("`{count}` is not an element count")))?;
                elements.push(Element {
                    name: (*name).to_owned(),
                    count,
                    properties: Vec::new(),
                });
            }
            ["property", "list", count, item, name] => {
                let element = elements
                    .last_mut()
                    .ok_or_else(|| syntax(location(), "a property before any element"))?;
                let scalar = |t: &str| {
                    Scalar::parse(t).ok_or_else(|| syntax(location(), format!("unknown type `{t}`")))
                };
                let count = scalar(count)?;
                if !count.is_integer() {
                    return Err(syntax(location(), "a list count must have an integer type"));
                }
                element.properties.push(Property::List {
                    name: (*name).to_owned(),
                    count,
                    item: scalar(item)?,
                });
            }
            ["property", ty, name] => {
                let element = elements
                    .last_mut()
                    .ok_or_else(|| syntax(location(), "a property before any element"))?;
                let ty =
                    Scalar::parse(ty).ok_or_else(|| syntax(location(), format!("unknown type `{ty}`")))?;
                element.properties.push(Property::Scalar {
                    name: (*name).to_owned(),
                    ty,
                });
            }
            _ => return Err(syntax(location(), format!("unexpected `{content}`"))),
        }
    }
    let format = format.ok_or_else(|| syntax("header", "no `format` line"))?;
    Ok((format, elements, body))
}

/// The vertex element's `x`, `y`, `z` columns and its texture coordinates' (`u v`, `s t`,
/// `texture_u texture_v` or `texture_s texture_t`), if any.
fn vertex_columns(element: &Element) -> Result<([usize; 3], Option<[usize; 2]>), MeshProblem> {
    let find = |names: &[&str]| {
        element
            .properties
            .iter()
            .position(|p| matches!(p, Property::Scalar { .. }) && names.contains(&p.name()))
    };
    let axis = |name: &str| {
        find(&[name]).ok_or_else(|| syntax("header", format!("the vertex element has no `{name}`")))
    };
    let xyz = [axis("x")?, axis("y")?, axis("z")?];
    let uv = [
        ["u", "v"],
        ["s", "t"],
        ["texture_u", "texture_v"],
        ["texture_s", "texture_t"],
    ]
    .iter()
    .find_map(|[a, b]| Some([find(&[a])?, find(&[b])?]));
    Ok((xyz, uv))
}

/// The face element's vertex-index list column and its per-corner `texcoord` list's, if any.
fn face_columns(element: &Element) -> Result<(usize, Option<usize>), MeshProblem> {
    let list = |names: &[&str]| {
        element
            .properties
            .iter()
            .position(|p| matches!(p, Property::List { .. }) && names.contains(&p.name()))
    };
    let indices = list(&["vertex_indices", "vertex_index"])
        .ok_or_else(|| syntax("header", "the face element has no `vertex_indices` list"))?;
    Ok((indices, list(&["texcoord"])))
}

/// A face (a polygon of vertex indices, checked against `vertices`) as a fan of triangles,
/// with its corners' texture coordinates when the faces carry them.
fn push_face(
    face: &[f64],
    texture: Option<&[f64]>,
    vertices: usize,
    location: &dyn Fn() -> String,
    (triangles, corner_uvs): (&mut Vec<[u32; 3]>, &mut Vec<Point2<Real>>),
) -> Result<(), MeshProblem> {
    if face.len() < 3 {
        return Err(syntax(location(), "a face needs at least three corners"));
    }
    let mut corners = Vec::with_capacity(face.len());
    for &index in face {
        if index < 0.0 || index.fract() != 0.0 || index >= vertices as f64 {
            return Err(MeshProblem::IndexOutOfRange {
                location: location(),
                index: index as i64,
                count: vertices,
                what: "vertices",
            });
        }
        corners.push(index as u32);
    }
    if let Some(texture) = texture
        && texture.len() != 2 * face.len()
    {
        return Err(syntax(
            location(),
            format!("{} texcoord values for {} corners", texture.len(), face.len()),
        ));
    }
    for j in 1..corners.len() - 1 {
        triangles.push([corners[0], corners[j], corners[j + 1]]);
        if let Some(texture) = texture {
            for c in [0, j, j + 1] {
                corner_uvs.push(Point2::new(texture[2 * c], texture[2 * c + 1]));
            }
        }
    }
    Ok(())
}

/// The mesh with its texture coordinates: per corner (`corner_uvs`, three per triangle) when
/// the faces carry them, else per vertex when the vertices do, else none.
fn textured_mesh(
    positions: Vec<Point3<Real>>,
    triangles: Vec<[u32; 3]>,
    vertex_uvs: Vec<Point2<Real>>,
    corner_uvs: Option<Vec<Point2<Real>>>,
) -> Result<TriangleMesh, MeshProblem> {
    let mesh = TriangleMesh::new(positions, triangles)?;
    if let Some(corner_uvs) = corner_uvs {
        let n = u32::try_from(corner_uvs.len())
            .map_err(|_| MeshProblem::TooLarge(format!("{} texture coordinates", corner_uvs.len())))?;
        let texture_triangles = (0..n / 3).map(|t| [3 * t, 3 * t + 1, 3 * t + 2]).collect();
        mesh.with_texture(TextureCoordinates {
            uvs: corner_uvs,
            triangles: texture_triangles,
        })
    } else if !vertex_uvs.is_empty() {
        let triangles = mesh.triangles().to_vec();
        mesh.with_texture(TextureCoordinates {
            uvs: vertex_uvs,
            triangles,
        })
    } else {
        Ok(mesh)
    }
}

/// Parses a PLY file (ASCII or binary). Vertices keep their order; polygons are
/// fan-triangulated.
///
/// # Errors
/// The first problem, naming the header line or the element (`vertex 12`, `face 3`): a
/// malformed header, a missing `x`/`y`/`z` or face index list, a truncated body, a NaN or
/// infinite coordinate, an index out of range, or no face.
pub fn parse_ply(bytes: &[u8]) -> Result<TriangleMesh, MeshProblem> {
    let parts = parse_elements(bytes)?;
    if !parts.has_faces {
        return Err(MeshProblem::Empty);
    }
    textured_mesh(
        parts.positions,
        parts.triangles,
        parts.vertex_uvs,
        parts.corner_uvs,
    )
}

/// The vertex positions of a PLY file, with or without faces (a point cloud).
///
/// # Errors
/// As [`parse_ply`], except that a file without faces is read.
pub fn parse_ply_points(bytes: &[u8]) -> Result<Vec<Point3<Real>>, MeshProblem> {
    Ok(parse_elements(bytes)?.positions)
}

/// What a PLY file holds: its vertices, triangles, texture coordinates (per vertex, and per
/// corner when the faces carry them), and whether it has a face element.
struct PlyParts {
    positions: Vec<Point3<Real>>,
    triangles: Vec<[u32; 3]>,
    vertex_uvs: Vec<Point2<Real>>,
    corner_uvs: Option<Vec<Point2<Real>>>,
    has_faces: bool,
}

/// [`parse_ply`]'s reading, faces or none.
fn parse_elements(bytes: &[u8]) -> Result<PlyParts, MeshProblem> {
    let (format, elements, body) = header(bytes)?;
    let mut body = match format {
        Format::Ascii => Body::Ascii(
            std::str::from_utf8(body)
                .map_err(|_| syntax("body", "an ASCII PLY body is not text"))?
                .split_ascii_whitespace(),
        ),
        Format::Binary { big_endian } => Body::Binary {
            bytes: body,
            big_endian,
        },
    };
    let mut positions: Vec<Point3<Real>> = Vec::new();
    let mut vertex_uvs: Vec<Point2<Real>> = Vec::new();
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut corner_uvs: Vec<Point2<Real>> = Vec::new();
    let mut has_vertices = false;
    let mut has_faces = false;
    let mut values: Vec<f64> = Vec::new();
    let mut corner_texture: Vec<f64> = Vec::new();
    for element in &elements {
        let is_vertex = element.name == "vertex";
        let is_face = element.name == "face";
        let (xyz, uv) = if is_vertex {
            has_vertices = true;
            vertex_columns(element)?
        } else {
            ([0; 3], None)
        };
        let (indices, texcoord) = if is_face {
            has_faces = true;
            face_columns(element)?
        } else {
            (0, None)
        };
        if is_vertex {
            // Every vertex takes at least three bytes (x, y and z as chars, or "0 0 0"), so a
            // header claiming more than the file holds reserves no more than the file.
            positions.reserve(element.count.min(bytes.len() / 3));
        }
        // An element without properties occupies no bytes: nothing to read, however many.
        let count = if element.properties.is_empty() {
            0
        } else {
            element.count
        };
        for k in 0..count {
            let location = || format!("{} {k}", element.name);
            values.clear();
            let mut face: Vec<f64> = Vec::new();
            corner_texture.clear();
            for (index, property) in element.properties.iter().enumerate() {
                match property {
                    Property::Scalar { ty, .. } => values.push(body.read(*ty, &location)?),
                    Property::List { count, item, .. } => {
                        values.push(f64::NAN);
                        let n = body.read(*count, &location)?;
                        if n < 0.0 {
                            return Err(syntax(location(), "a negative list length"));
                        }
                        let target = if is_face && index == indices {
                            Some(&mut face)
                        } else if is_face && Some(index) == texcoord {
                            Some(&mut corner_texture)
                        } else {
                            None
                        };
                        match target {
                            Some(target) => {
                                for _ in 0..n as usize {
                                    target.push(body.read(*item, &location)?);
                                }
                            }
                            None => {
                                for _ in 0..n as usize {
                                    body.read(*item, &location)?;
                                }
                            }
                        }
                    }
                }
            }
            if is_vertex {
                let p = Point3::new(values[xyz[0]], values[xyz[1]], values[xyz[2]]);
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(MeshProblem::NonFinite { location: location() });
                }
                positions.push(p);
                if let Some([a, b]) = uv {
                    vertex_uvs.push(Point2::new(values[a], values[b]));
                }
            }
            if is_face {
                let textured = texcoord.map(|_| corner_texture.as_slice());
                push_face(
                    &face,
                    textured,
                    positions.len(),
                    &location,
                    (&mut triangles, &mut corner_uvs),
                )?;
            }
        }
    }
    if !body.is_exhausted() {
        return Err(syntax("body", "data after the last element"));
    }
    if !has_vertices {
        return Err(syntax("header", "no vertex element"));
    }
    let corner_textured = elements
        .iter()
        .any(|e| e.name == "face" && e.properties.iter().any(|p| p.name() == "texcoord"));
    Ok(PlyParts {
        positions,
        triangles,
        vertex_uvs,
        corner_uvs: corner_textured.then_some(corner_uvs),
        has_faces,
    })
}

/// Whether a texture is per vertex (one coordinate per vertex, indexed like the triangles).
fn per_vertex(mesh: &TriangleMesh, texture: &TextureCoordinates) -> bool {
    texture.uvs.len() == mesh.positions().len() && texture.triangles == mesh.triangles()
}

/// Encodes a mesh as PLY with `double` coordinates. Texture coordinates are written per vertex
/// (`u`, `v`) when they are indexed like the triangles, per corner (`texcoord` lists)
/// otherwise. [`parse_ply`] reads back the same positions, triangles and per-corner texture
/// coordinates bit for bit.
pub fn encode_ply(mesh: &TriangleMesh, encoding: PlyEncoding) -> Vec<u8> {
    let texture = mesh.texture();
    let vertex_uv = texture.filter(|t| per_vertex(mesh, t));
    let corner_uv = texture.filter(|t| !per_vertex(mesh, t));
    let mut header = String::from("ply\n");
    header.push_str(match encoding {
        PlyEncoding::Ascii => "format ascii 1.0\n",
        PlyEncoding::BinaryLittleEndian => "format binary_little_endian 1.0\n",
    });
    header.push_str("comment written by splineface\n");
    let _ = writeln!(header, "element vertex {}", mesh.positions().len());
    header.push_str("property double x\nproperty double y\nproperty double z\n");
    if vertex_uv.is_some() {
        header.push_str("property double u\nproperty double v\n");
    }
    let normals = mesh.normals();
    if normals.is_some() {
        header.push_str("property double nx\nproperty double ny\nproperty double nz\n");
    }
    let _ = writeln!(header, "element face {}", mesh.triangles().len());
    header.push_str("property list uchar uint vertex_indices\n");
    if corner_uv.is_some() {
        header.push_str("property list uchar double texcoord\n");
    }
    header.push_str("end_header\n");
    let mut out = header.into_bytes();
    match encoding {
        PlyEncoding::Ascii => {
            let mut text = String::new();
            for (k, p) in mesh.positions().iter().enumerate() {
                let _ = write!(text, "{:?} {:?} {:?}", p.x, p.y, p.z);
                if let Some(t) = vertex_uv {
                    let _ = write!(text, " {:?} {:?}", t.uvs[k].x, t.uvs[k].y);
                }
                if let Some(n) = normals {
                    let _ = write!(text, " {:?} {:?} {:?}", n[k].x, n[k].y, n[k].z);
                }
                text.push('\n');
            }
            for (k, f) in mesh.triangles().iter().enumerate() {
                let _ = write!(text, "3 {} {} {}", f[0], f[1], f[2]);
                if let Some(t) = corner_uv {
                    text.push_str(" 6");
                    for &c in &t.triangles[k] {
                        let uv = t.uvs[c as usize];
                        let _ = write!(text, " {:?} {:?}", uv.x, uv.y);
                    }
                }
                text.push('\n');
            }
            out.extend_from_slice(text.as_bytes());
        }
        PlyEncoding::BinaryLittleEndian => {
            for (k, p) in mesh.positions().iter().enumerate() {
                for c in p.iter() {
                    out.extend_from_slice(&c.to_le_bytes());
                }
                if let Some(t) = vertex_uv {
                    out.extend_from_slice(&t.uvs[k].x.to_le_bytes());
                    out.extend_from_slice(&t.uvs[k].y.to_le_bytes());
                }
                if let Some(n) = normals {
                    for c in n[k].iter() {
                        out.extend_from_slice(&c.to_le_bytes());
                    }
                }
            }
            for (k, f) in mesh.triangles().iter().enumerate() {
                out.push(3);
                for i in f {
                    out.extend_from_slice(&i.to_le_bytes());
                }
                if let Some(t) = corner_uv {
                    out.push(6);
                    for &c in &t.triangles[k] {
                        let uv = t.uvs[c as usize];
                        out.extend_from_slice(&uv.x.to_le_bytes());
                        out.extend_from_slice(&uv.y.to_le_bytes());
                    }
                }
            }
        }
    }
    out
}
