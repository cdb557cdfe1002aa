//! Binary glTF 2.0 (`.glb`) export of a triangle mesh, optionally textured.
//!
//! The JSON chunk is built with `serde_json` rather than `gltf-json`'s structs, whose fields
//! change with that crate's cargo features; the tests read every file back with the `gltf`
//! crate, which validates it against the specification.

use std::collections::HashMap;

use nalgebra::{Point2, Point3, Vector3};
use serde_json::{Value, json};

use super::{MeshError, MeshProblem, TriangleMesh};
use crate::Real;

/// A texture image for [`encode_glb`]: PNG bytes and their size.
#[derive(Debug, Clone, Copy)]
pub struct PngTexture<'a> {
    /// The encoded PNG file.
    pub png: &'a [u8],
}

/// One vertex as glTF needs it: a position, maybe a normal and maybe texture coordinates.
fn unweld(mesh: &TriangleMesh) -> (Vec<u32>, Vec<Option<u32>>, Vec<u32>) {
    // glTF attributes are per vertex: a position used with two texture coordinates becomes two
    // vertices. Returns the source position of each output vertex, its texture coordinate and
    // the output triangles.
    let mut map: HashMap<(u32, Option<u32>), u32> = HashMap::new();
    let mut sources = Vec::new();
    let mut uvs = Vec::new();
    let mut indices = Vec::with_capacity(3 * mesh.triangles().len());
    for (k, t) in mesh.triangles().iter().enumerate() {
        for (c, &vertex) in t.iter().enumerate() {
            let uv = mesh.texture().map(|x| x.triangles[k][c]);
            let key = (vertex, uv);
            let next = sources.len() as u32;
            let index = *map.entry(key).or_insert_with(|| {
                sources.push(vertex);
                uvs.push(uv);
                next
            });
            indices.push(index);
        }
    }
    (sources, uvs, indices)
}

fn push_f32(buffer: &mut Vec<u8>, values: impl Iterator<Item = Real>) {
    for v in values {
        buffer.extend_from_slice(&(v as f32).to_le_bytes());
    }
}

fn pad(buffer: &mut Vec<u8>, with: u8) {
    while !buffer.len().is_multiple_of(4) {
        buffer.push(with);
    }
}

/// Encodes the mesh as a binary glTF 2.0 file: one node, one mesh, one primitive with
/// `POSITION`, `NORMAL` (when the mesh has normals), `TEXCOORD_0` (when it has texture
/// coordinates; flipped to glTF's top-left origin) and `u32` indices, and a PBR material: the
/// texture as base colour when given, else a plain skin tone. Positions are `f32`, as glTF
/// requires. Vertices are duplicated where a position is used with several texture
/// coordinates.
pub fn encode_glb(mesh: &TriangleMesh, name: &str, texture: Option<PngTexture<'_>>) -> Vec<u8> {
    let (sources, uvs, indices) = unweld(mesh);
    let positions: Vec<Point3<Real>> = sources.iter().map(|&i| mesh.positions()[i as usize]).collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &positions {
        for c in 0..3 {
            lo[c] = lo[c].min(p[c] as f32);
            hi[c] = hi[c].max(p[c] as f32);
        }
    }

    let mut bin: Vec<u8> = Vec::new();
    let mut views: Vec<Value> = Vec::new();
    let mut accessors: Vec<Value> = Vec::new();
    let mut attributes = serde_json::Map::new();
    let mut add_view = |bin: &mut Vec<u8>, start: usize, target: Option<u32>| -> usize {
        let mut view = json!({ "buffer": 0, "byteOffset": start, "byteLength": bin.len() - start });
        if let Some(target) = target {
            view["target"] = json!(target);
        }
        views.push(view);
        views.len() - 1
    };
    const ARRAY_BUFFER: u32 = 34962;
    const ELEMENT_ARRAY_BUFFER: u32 = 34963;
    const FLOAT: u32 = 5126;
    const UNSIGNED_INT: u32 = 5125;

    let start = bin.len();
    push_f32(&mut bin, positions.iter().flat_map(|p| [p.x, p.y, p.z]));
    let view = add_view(&mut bin, start, Some(ARRAY_BUFFER));
    accessors.push(json!({
        "bufferView": view, "componentType": FLOAT, "count": positions.len(), "type": "VEC3",
        "min": lo, "max": hi,
    }));
    attributes.insert("POSITION".into(), json!(accessors.len() - 1));

    if let Some(normals) = mesh.normals() {
        let start = bin.len();
        let picked: Vec<Vector3<Real>> = sources.iter().map(|&i| normals[i as usize]).collect();
        push_f32(&mut bin, picked.iter().flat_map(|n| [n.x, n.y, n.z]));
        let view = add_view(&mut bin, start, Some(ARRAY_BUFFER));
        accessors.push(json!({
            "bufferView": view, "componentType": FLOAT, "count": positions.len(), "type": "VEC3",
        }));
        attributes.insert("NORMAL".into(), json!(accessors.len() - 1));
    }
    if let Some(coordinates) = mesh.texture() {
        let start = bin.len();
        let picked: Vec<Point2<Real>> = uvs
            .iter()
            .map(|uv| coordinates.uvs[uv.expect("textured meshes have a coordinate per corner") as usize])
            .collect();
        push_f32(&mut bin, picked.iter().flat_map(|t| [t.x, 1.0 - t.y]));
        let view = add_view(&mut bin, start, Some(ARRAY_BUFFER));
        accessors.push(json!({
            "bufferView": view, "componentType": FLOAT, "count": positions.len(), "type": "VEC2",
        }));
        attributes.insert("TEXCOORD_0".into(), json!(accessors.len() - 1));
    }
    let start = bin.len();
    for i in &indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let view = add_view(&mut bin, start, Some(ELEMENT_ARRAY_BUFFER));
    accessors.push(json!({
        "bufferView": view, "componentType": UNSIGNED_INT, "count": indices.len(), "type": "SCALAR",
    }));
    let index_accessor = accessors.len() - 1;

    let mut document = json!({
        "asset": { "version": "2.0", "generator": format!("splineface {}", env!("CARGO_PKG_VERSION")) },
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": name }],
        "meshes": [{
            "name": name,
            "primitives": [{ "attributes": attributes, "indices": index_accessor, "material": 0, "mode": 4 }],
        }],
        "materials": [{
            "name": "skin",
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.87, 0.72, 0.62, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.7,
            },
        }],
    });
    if let (Some(texture), true) = (texture, mesh.texture().is_some()) {
        let start = bin.len();
        bin.extend_from_slice(texture.png);
        let view = add_view(&mut bin, start, None);
        pad(&mut bin, 0);
        document["images"] = json!([{ "bufferView": view, "mimeType": "image/png" }]);
        document["samplers"] =
            json!([{ "magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071 }]);
        document["textures"] = json!([{ "source": 0, "sampler": 0 }]);
        document["materials"][0]["pbrMetallicRoughness"] = json!({
            "baseColorTexture": { "index": 0 }, "metallicFactor": 0.0, "roughnessFactor": 0.7,
        });
    }
    pad(&mut bin, 0);
    document["buffers"] = json!([{ "byteLength": bin.len() }]);
    document["bufferViews"] = Value::Array(views);
    document["accessors"] = Value::Array(accessors);

    let mut text = serde_json::to_vec(&document).expect("JSON values always serialise");
    pad(&mut text, b' ');
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// The largest binary glTF file: its header counts bytes in 32 bits.
pub const MAX_GLB_BYTES: usize = u32::MAX as usize;

/// Writes a binary glTF file (see [`encode_glb`]), all or nothing.
///
/// # Errors
/// A [`MeshError`] naming the file: [`MeshProblem::TooLarge`] past 4 GiB, or the I/O error.
pub fn write_glb(
    path: &std::path::Path,
    mesh: &TriangleMesh,
    name: &str,
    texture: Option<PngTexture<'_>>,
) -> Result<(), MeshError> {
    let error = |problem| MeshError {
        file: path.to_path_buf(),
        problem,
    };
    let estimate =
        40 * mesh.positions().len() + 12 * mesh.triangles().len() + texture.map_or(0, |t| t.png.len());
    if estimate > MAX_GLB_BYTES {
        return Err(error(MeshProblem::TooLarge(format!("about {estimate} bytes"))));
    }
    let bytes = encode_glb(mesh, name, texture);
    if bytes.len() > MAX_GLB_BYTES {
        return Err(error(MeshProblem::TooLarge(format!("{} bytes", bytes.len()))));
    }
    crate::io::write_atomically(path, &bytes).map_err(|e| error(e.into()))
}
