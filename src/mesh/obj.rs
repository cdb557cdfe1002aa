//! Wavefront OBJ: `v`, `vt` and `f` are read; normals, groups, materials and other statements
//! are skipped.

use std::fmt::Write;

use nalgebra::{Point2, Point3};

use super::{MeshError, MeshProblem, TextureCoordinates, TriangleMesh, syntax};
use crate::Real;

/// One face corner as written: position index and optional texture index, 1-based or
/// negative (relative), not yet resolved.
#[derive(Clone, Copy)]
struct Corner {
    position: i64,
    texture: Option<i64>,
}

/// Parses OBJ text. Vertices keep their order in the file; faces with more than three corners
/// are fan-triangulated; texture coordinates are kept when every face has them (a file where
/// only some faces have them yields no texture coordinates). Negative (relative) indices are
/// resolved against the vertices read so far; positive ones may refer forward.
///
/// # Errors
/// The first problem, with its line: a malformed number, a face with fewer than three corners,
/// a zero or out-of-range index, a NaN or infinite coordinate, or no face at all.
pub fn parse_obj(text: &str) -> Result<TriangleMesh, MeshProblem> {
    let mut positions: Vec<Point3<Real>> = Vec::new();
    let mut uvs: Vec<Point2<Real>> = Vec::new();
    // Triangles as resolved-later corners, with the line they come from.
    let mut corners: Vec<([Corner; 3], usize)> = Vec::new();
    let mut face: Vec<Corner> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let location = || format!("line {line}");
        let content = raw.split('#').next().unwrap_or("");
        let mut fields = content.split_whitespace();
        let Some(keyword) = fields.next() else {
            continue;
        };
        match keyword {
            "v" => {
                let values = numbers(fields, line, 3, 7)?;
                positions.push(Point3::new(values[0], values[1], values[2]));
            }
            "vt" => {
                let values = numbers(fields, line, 1, 3)?;
                uvs.push(Point2::new(values[0], values.get(1).copied().unwrap_or(0.0)));
            }
            "f" => {
                face.clear();
                for field in fields {
                    face.push(corner(field, line, positions.len(), uvs.len())?);
                }
                if face.len() < 3 {
                    return Err(syntax(location(), "a face needs at least three corners"));
                }
                for k in 1..face.len() - 1 {
                    corners.push(([face[0], face[k], face[k + 1]], line));
                }
            }
            _ => {}
        }
    }
    if corners.is_empty() {
        return Err(MeshProblem::Empty);
    }
    let textured = corners.iter().all(|(c, _)| c.iter().all(|c| c.texture.is_some()));
    let mut triangles = Vec::with_capacity(corners.len());
    let mut texture_triangles = Vec::with_capacity(if textured { corners.len() } else { 0 });
    for (c, line) in &corners {
        let mut triangle = [0u32; 3];
        let mut texture = [0u32; 3];
        for k in 0..3 {
            triangle[k] = resolve(c[k].position, positions.len(), *line, "vertices")?;
            if textured {
                let t = c[k].texture.unwrap_or(0);
                texture[k] = resolve(t, uvs.len(), *line, "texture coordinates")?;
            }
        }
        triangles.push(triangle);
        if textured {
            texture_triangles.push(texture);
        }
    }
    // Coordinates were checked for finiteness as they were read.
    let mesh = TriangleMesh::new(positions, triangles)?;
    if textured {
        mesh.with_texture(TextureCoordinates {
            uvs,
            triangles: texture_triangles,
        })
    } else {
        Ok(mesh)
    }
}

fn numbers<'a>(
    fields: impl Iterator<Item = &'a str>,
    line: usize,
    min: usize,
    max: usize,
) -> Result<Vec<Real>, MeshProblem> {
    let mut values = Vec::with_capacity(max);
    for field in fields {
        if values.len() == max {
            return Err(syntax(format!("line {line}"), format!("more than {max} numbers")));
        }
        let value: Real = field
            .parse()
            .map_err(|_| syntax(format!("line {line}"), format!("`{field}` is not a number")))?;
        if !value.is_finite() {
            return Err(MeshProblem::NonFinite {
                location: format!("line {line}"),
            });
        }
        values.push(value);
    }
    if values.len() < min {
        return Err(syntax(
            format!("line {line}"),
            format!("expected at least {min} numbers, found {}", values.len()),
        ));
    }
    Ok(values)
}

/// Parses `v`, `v/vt`, `v//vn` or `v/vt/vn`. Negative indices are made absolute (1-based) here,
/// against the counts read so far.
fn corner(field: &str, line: usize, positions: usize, uvs: usize) -> Result<Corner, MeshProblem> {
    let mut parts = field.split('/');
    let index = |part: Option<&str>, count: usize, what: &'static str| -> Result<Option<i64>, MeshProblem> {
        match part {
            None | Some("") => Ok(None),
            Some(text) => {
                let value: i64 = text
                    .parse()
                    .map_err(|_| syntax(format!("line {line}"), format!("`{field}` is not a face corner")))?;
                match value {
                    0 => Err(MeshProblem::IndexOutOfRange {
                        location: format!("line {line}"),
                        index: 0,
                        count,
                        what,
                    }),
                    v if v < 0 => Ok(Some(count as i64 + v + 1)),
                    v => Ok(Some(v)),
                }
            }
        }
    };
    let position = index(parts.next(), positions, "vertices")?
        .ok_or_else(|| syntax(format!("line {line}"), format!("`{field}` has no vertex index")))?;
    let texture = index(parts.next(), uvs, "texture coordinates")?;
    if parts.nth(1).is_some() {
        return Err(syntax(
            format!("line {line}"),
            format!("`{field}` is not a face corner"),
        ));
    }
    Ok(Corner { position, texture })
}

/// A 1-based (already made absolute) index to 0-based, checked against `count`.
fn resolve(index: i64, count: usize, line: usize, what: &'static str) -> Result<u32, MeshProblem> {
    if index < 1 || index as u64 > count as u64 {
        return Err(MeshProblem::IndexOutOfRange {
            location: format!("line {line}"),
            index,
            count,
            what,
        });
    }
    u32::try_from(index - 1).map_err(|_| MeshProblem::TooLarge(format!("index {index}")))
}

/// Writes a mesh as OBJ text: `v` lines in order, `vt` lines if textured, `vn` lines if the
/// mesh has normals (one per vertex, indexed like the positions), then `f` lines (`a`, `a/ta`,
/// `a//na` or `a/ta/na`). Numbers are written in their shortest exact form, so [`parse_obj`]
/// reads back the same positions, triangles and texture coordinates bit for bit.
pub fn format_obj(mesh: &TriangleMesh) -> String {
    format_obj_with_material(mesh, None)
}

/// [`format_obj`] with `mtllib FILE` and `usemtl NAME` lines naming a material.
pub(crate) fn format_obj_with_material(mesh: &TriangleMesh, material: Option<(&str, &str)>) -> String {
    let mut out = String::with_capacity(40 * (mesh.positions().len() + mesh.triangles().len()));
    out.push_str("# written by splineface\n");
    if let Some((library, _)) = material {
        let _ = writeln!(out, "mtllib {library}");
    }
    for p in mesh.positions() {
        let _ = writeln!(out, "v {:?} {:?} {:?}", p.x, p.y, p.z);
    }
    if let Some(texture) = mesh.texture() {
        for t in &texture.uvs {
            let _ = writeln!(out, "vt {:?} {:?}", t.x, t.y);
        }
    }
    if let Some(normals) = mesh.normals() {
        for n in normals {
            let _ = writeln!(out, "vn {:?} {:?} {:?}", n.x, n.y, n.z);
        }
    }
    if let Some((_, name)) = material {
        let _ = writeln!(out, "usemtl {name}");
    }
    let has_normals = mesh.normals().is_some();
    for (k, f) in mesh.triangles().iter().enumerate() {
        out.push('f');
        for (c, &corner) in f.iter().enumerate() {
            let v = corner + 1;
            match (mesh.texture(), has_normals) {
                (Some(t), true) => {
                    let _ = write!(out, " {v}/{}/{v}", t.triangles[k][c] + 1);
                }
                (Some(t), false) => {
                    let _ = write!(out, " {v}/{}", t.triangles[k][c] + 1);
                }
                (None, true) => {
                    let _ = write!(out, " {v}//{v}");
                }
                (None, false) => {
                    let _ = write!(out, " {v}");
                }
            }
        }
        out.push('\n');
    }
    out
}

/// The material library of a textured OBJ: one material, `face`, whose diffuse map is the
/// image file `texture` (named relative to the `.mtl`).
pub fn format_mtl(texture: &str) -> String {
    format!(
        "# written by splineface\nnewmtl face\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {texture}\n"
    )
}

/// Writes a textured OBJ: `path` (the mesh, which must have texture coordinates to be
/// textured), its material library beside it (`path` with extension `.mtl`,
/// [`format_mtl`]) and the texture (`.png`, the PNG bytes given), naming each other by file
/// name so the three can move together. Without texture coordinates or texture, writes the
/// OBJ alone. All or nothing.
///
/// # Errors
/// A [`MeshError`] naming the first file that could not be written (files this call wrote
/// are removed again), or [`MeshProblem::Syntax`] for a file name that is not UTF-8 text
/// (the OBJ must name the MTL, and the MTL the PNG).
pub fn write_obj(
    path: &std::path::Path,
    mesh: &TriangleMesh,
    texture: Option<&[u8]>,
) -> Result<(), MeshError> {
    let error = |file: &std::path::Path, problem| MeshError {
        file: file.to_path_buf(),
        problem,
    };
    let texture = texture.filter(|_| mesh.texture().is_some());
    let Some(png) = texture else {
        return crate::io::write_atomically(path, format_obj(mesh).as_bytes())
            .map_err(|e| error(path, e.into()));
    };
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .ok_or_else(|| error(path, syntax("file name", "the file name is not UTF-8 text")))?;
    let (mtl, image) = (path.with_extension("mtl"), path.with_extension("png"));
    let obj = format_obj_with_material(mesh, Some((&format!("{stem}.mtl"), "face")));
    crate::io::write_files_atomically(&[
        (image, png.to_vec()),
        (mtl, format_mtl(&format!("{stem}.png")).into_bytes()),
        (path.to_path_buf(), obj.into_bytes()),
    ])
    .map_err(|(file, e)| error(&file, e.into()))
}
