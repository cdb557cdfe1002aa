//! Mesh files: hand-worked OBJ/PLY/GLB files, exact round trips, rejection of malformed input,
//! and the real ICT scan checked against `tobj`.

use std::path::{Path, PathBuf};

use nalgebra::{Point2, Point3};
use proptest::prelude::*;
use splineface::mesh::{
    MeshProblem, PlyEncoding, TextureCoordinates, TriangleMesh, encode_ply, format_obj, parse_obj, parse_ply,
    read_mesh, write_mesh,
};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("splineface-mesh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

const SQUARE_OBJ: &str = "\
# a unit square and an unused vertex, which must keep its place
o square
v 0 0 0
v 1 0 0
v 9 9 9 0.5 0.5 0.5
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
s off
f 1/1/1 2/2/1 4/3/1 5/4/1
f -5/1 -4/2 -2/3
";

#[test]
fn obj_reads_in_file_order_and_fans_polygons() {
    let mesh = parse_obj(SQUARE_OBJ).unwrap();
    assert_eq!(mesh.positions().len(), 5);
    assert_eq!(mesh.positions()[2], Point3::new(9.0, 9.0, 9.0));
    // The quad fans from its first corner; the relative face resolves against 5 vertices.
    assert_eq!(mesh.triangles(), &[[0, 1, 3], [0, 3, 4], [0, 1, 3]]);
    let texture = mesh.texture().unwrap();
    assert_eq!(texture.triangles, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2]]);
    assert_eq!(texture.uvs[2], Point2::new(1.0, 1.0));
}

#[test]
fn obj_with_partial_texture_drops_it() {
    let mesh = parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1 2 3\n").unwrap();
    assert!(mesh.texture().is_none());
    assert_eq!(mesh.triangles().len(), 2);
}

fn problem(text: &str) -> MeshProblem {
    parse_obj(text).unwrap_err()
}

#[test]
fn obj_rejects_malformed_input() {
    let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
    let cases = [
        (
            format!("{tri}f 1 2 4\n"),
            "line 4: index 4 is out of range (3 vertices)",
        ),
        (format!("{tri}f 0 1 2\n"), "line 4: index 0 is out of range"),
        (
            format!("{tri}f 1 2\n"),
            "line 4: a face needs at least three corners",
        ),
        (format!("{tri}f 1 2 -4\n"), "line 4: index 0 is out of range"),
        (format!("{tri}f 1/9 2/9 3/9\n"), "texture coordinates"),
        (format!("{tri}f 1 2 x\n"), "line 4: `x` is not a face corner"),
        (
            format!("v 0 NaN 0\n{tri}f 1 2 3\n"),
            "line 1: a coordinate is not finite",
        ),
        (
            format!("v 0 inf 0\n{tri}f 1 2 3\n"),
            "line 1: a coordinate is not finite",
        ),
        (
            "v 0 0\nf 1 1 1\n".to_owned(),
            "line 1: expected at least 3 numbers",
        ),
        ("v 0 0 zero\n".to_owned(), "line 1: `zero` is not a number"),
        (tri.to_owned(), "no triangles"),
        (format!("{tri}f 1/1/1/1 2 3\n"), "is not a face corner"),
    ];
    for (text, expected) in cases {
        let message = problem(&text).to_string();
        assert!(
            message.contains(expected),
            "{text:?}: got {message:?}, expected {expected:?}"
        );
    }
}

/// A random mesh: `n` vertices, `m` triangles, optional per-corner texture.
fn random_mesh() -> impl Strategy<Value = TriangleMesh> {
    (3usize..40, 1usize..60, any::<bool>(), any::<bool>()).prop_flat_map(|(n, m, textured, per_vertex)| {
        (
            proptest::collection::vec(proptest::array::uniform3(-1e6f64..1e6), n),
            proptest::collection::vec(proptest::array::uniform3(0..n as u32), m),
            proptest::collection::vec(proptest::array::uniform2(-2f64..2.0), 1..50),
        )
            .prop_map(move |(positions, triangles, uvs)| {
                let positions = positions.into_iter().map(Point3::from).collect();
                let mesh = TriangleMesh::new(positions, triangles.clone()).unwrap();
                if !textured {
                    return mesh;
                }
                let texture = if per_vertex {
                    TextureCoordinates {
                        uvs: (0..n).map(|k| Point2::from(uvs[k % uvs.len()])).collect(),
                        triangles,
                    }
                } else {
                    let len = uvs.len() as u32;
                    TextureCoordinates {
                        triangles: triangles.iter().map(|t| t.map(|i| (i * 7 + 3) % len)).collect(),
                        uvs: uvs.into_iter().map(Point2::from).collect(),
                    }
                };
                mesh.with_texture(texture).unwrap()
            })
    })
}

/// Each triangle's three texture coordinates, for comparing textures indexed differently.
fn corner_uvs(mesh: &TriangleMesh) -> Option<Vec<[Point2<f64>; 3]>> {
    mesh.texture()
        .map(|t| t.triangles.iter().map(|c| c.map(|i| t.uvs[i as usize])).collect())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn obj_round_trip_is_exact(mesh in random_mesh()) {
        prop_assert_eq!(parse_obj(&format_obj(&mesh)).unwrap(), mesh);
    }

    #[test]
    fn ply_round_trips_are_exact(mesh in random_mesh()) {
        for encoding in [PlyEncoding::Ascii, PlyEncoding::BinaryLittleEndian] {
            let back = parse_ply(&encode_ply(&mesh, encoding)).unwrap();
            prop_assert_eq!(back.positions(), mesh.positions());
            prop_assert_eq!(back.triangles(), mesh.triangles());
            prop_assert_eq!(corner_uvs(&back), corner_uvs(&mesh));
        }
    }

    /// No prefix of a valid binary file reads as a mesh, and none panics.
    #[test]
    fn truncated_ply_is_refused(mesh in random_mesh(), cut in 0.0f64..1.0) {
        let bytes = encode_ply(&mesh, PlyEncoding::BinaryLittleEndian);
        let keep = ((bytes.len() - 1) as f64 * cut) as usize;
        prop_assert!(parse_ply(&bytes[..keep]).is_err());
    }
}

/// A hand-built big-endian PLY: float32 coordinates, a colour property, an extra element
/// before the faces, a quad.
#[test]
fn ply_big_endian_with_extras() {
    let mut bytes = b"ply\nformat binary_big_endian 1.0\ncomment hand-made\nelement vertex 4\n\
property float x\nproperty float y\nproperty float z\nproperty uchar red\n\
element material 2\nproperty list uchar int ids\n\
element face 1\nproperty uchar flags\nproperty list uchar int vertex_indices\nend_header\n"
        .to_vec();
    for (k, p) in [
        [0.0f32, 0.0, 0.0],
        [1.0, 0.0, 0.5],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, -0.25],
    ]
    .iter()
    .enumerate()
    {
        for c in p {
            bytes.extend_from_slice(&c.to_be_bytes());
        }
        bytes.push(k as u8);
    }
    for _ in 0..2 {
        bytes.push(2);
        bytes.extend_from_slice(&7i32.to_be_bytes());
        bytes.extend_from_slice(&8i32.to_be_bytes());
    }
    bytes.push(0xff);
    bytes.push(4);
    for i in [0i32, 1, 2, 3] {
        bytes.extend_from_slice(&i.to_be_bytes());
    }
    let mesh = parse_ply(&bytes).unwrap();
    assert_eq!(mesh.positions()[1], Point3::new(1.0, 0.0, 0.5));
    assert_eq!(mesh.positions()[3], Point3::new(0.0, 1.0, -0.25));
    assert_eq!(mesh.triangles(), &[[0, 1, 2], [0, 2, 3]]);
    assert!(mesh.texture().is_none());
    // One byte more is refused.
    bytes.push(0);
    assert!(
        parse_ply(&bytes)
            .unwrap_err()
            .to_string()
            .contains("data after the last element")
    );
}

#[test]
fn ply_ascii_with_vertex_uvs() {
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
property double z\nproperty float s\nproperty float t\nelement face 1\n\
property list uchar uint vertex_index\nend_header\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n";
    let mesh = parse_ply(text.as_bytes()).unwrap();
    let texture = mesh.texture().unwrap();
    assert_eq!(texture.uvs[2], Point2::new(0.0, 1.0));
    assert_eq!(texture.triangles, mesh.triangles());
}

#[test]
fn ply_rejects_malformed_input() {
    let head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let cases = [
        (
            format!("{head}0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
            "face 0: index 3 is out of range (3 vertices)",
        ),
        (
            format!("{head}0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
            "face 0: index -1 is out of range",
        ),
        (
            format!("{head}0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"),
            "vertex 1: a coordinate is not finite",
        ),
        (
            format!("{head}0 0 0\n1 0 0\n0 1 0\n2 0 1\n"),
            "face 0: a face needs at least three corners",
        ),
        (
            format!("{head}0 0 0\n1 0 0\n"),
            "truncated: vertex 2 is incomplete",
        ),
        (
            format!("{head}0 0 0\n1 0 0\n0 one 0\n3 0 1 2\n"),
            "vertex 2: `one` is not a number",
        ),
        (
            head.replace("property double z\n", ""),
            "the vertex element has no `z`",
        ),
        (head.replace("format ascii 1.0\n", ""), "no `format` line"),
        (head.replace("double x", "complex x"), "unknown type `complex`"),
        (head.replace("ply\n", "plx\n"), "not a PLY file"),
        ("ply\nformat ascii 1.0\n".to_owned(), "no `end_header` line"),
    ];
    for (text, expected) in cases {
        let message = parse_ply(text.as_bytes()).unwrap_err().to_string();
        assert!(
            message.contains(expected),
            "{text:?}: got {message:?}, expected {expected:?}"
        );
    }
}

/// A glTF document with two nodes sharing one mesh (u16 indices, TEXCOORD_0), one translated
/// and one a child of a scaled parent, and its one buffer's bytes (the buffer has no URI).
fn gltf_parts() -> (serde_json::Value, Vec<u8>) {
    let positions: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let uvs: [[f32; 2]; 3] = [[0.0, 0.0], [1.0, 0.0], [0.0, 0.25]];
    let indices: [u16; 4] = [0, 1, 2, 0]; // three used, one of padding
    let mut bin = Vec::new();
    for p in positions.iter().flatten().chain(uvs.iter().flatten()) {
        bin.extend_from_slice(&p.to_le_bytes());
    }
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"mesh": 0, "translation": [10.0, 0.0, 0.0]},
            {"scale": [2.0, 2.0, 2.0], "children": [2]},
            {"mesh": 0}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2}]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 24},
            {"buffer": 0, "byteOffset": 60, "byteLength": 8}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 3, "type": "SCALAR"}
        ]
    });
    (json, bin)
}

/// [`gltf_parts`] as a GLB.
fn glb() -> Vec<u8> {
    let (json, bin) = gltf_parts();
    let mut json = serde_json::to_vec(&json).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

#[test]
fn glb_places_meshes_by_their_nodes() {
    let path = scratch("two.glb");
    std::fs::write(&path, glb()).unwrap();
    let mesh = read_mesh(&path).unwrap();
    assert_eq!(mesh.positions().len(), 6);
    assert_eq!(mesh.positions()[1], Point3::new(11.0, 0.0, 0.0));
    assert_eq!(mesh.positions()[5], Point3::new(0.0, 2.0, 0.0));
    assert_eq!(mesh.triangles(), &[[0, 1, 2], [3, 4, 5]]);
    let texture = mesh.texture().unwrap();
    // v is flipped to point up.
    assert_eq!(texture.uvs[2], Point2::new(0.0, 0.75));
}

#[test]
fn gltf_buffers_come_from_files_and_data_uris_only() {
    let dir = scratch("gltf-buffers");
    std::fs::create_dir_all(&dir).unwrap();
    let (mut json, bin) = gltf_parts();
    let expected = read_mesh(&{
        let path = dir.join("reference.glb");
        std::fs::write(&path, glb()).unwrap();
        path
    })
    .unwrap();
    let read_with_uri = |json: &mut serde_json::Value, uri: &str| {
        json["buffers"][0]["uri"] = uri.into();
        let path = dir.join("mesh.gltf");
        std::fs::write(&path, serde_json::to_vec(json).unwrap()).unwrap();
        read_mesh(&path)
    };
    // A file next to the glTF, its name percent-escaped; a longer file is cut to byteLength.
    let mut longer = bin.clone();
    longer.extend_from_slice(&[0xff; 16]);
    std::fs::write(dir.join("the mesh.bin"), &longer).unwrap();
    let mesh = read_with_uri(&mut json, "the%20mesh.bin").unwrap();
    assert_eq!(mesh.positions(), expected.positions());
    assert_eq!(mesh.triangles(), expected.triangles());
    // The same bytes as a data URI.
    let data = format!("data:application/octet-stream;base64,{}", base64::encode(&bin));
    assert_eq!(
        read_with_uri(&mut json, &data).unwrap().positions(),
        expected.positions()
    );
    // Without a folder to look in, an external buffer is an error, not a read of the cwd.
    json["buffers"][0]["uri"] = "the%20mesh.bin".into();
    let message = splineface::mesh::parse_gltf(&serde_json::to_vec(&json).unwrap(), None)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("buffer 0: lives in another file (the mesh.bin)"),
        "{message}"
    );
    // Refused: a device (reading /dev/zero to its end would never return), a folder, a short
    // file, a missing file, another scheme, a data URI shorter than declared.
    std::fs::write(dir.join("short.bin"), &bin[..50]).unwrap();
    std::fs::create_dir_all(dir.join("folder.bin")).unwrap();
    for (uri, expected) in [
        ("file:///dev/zero", "/dev/zero is not a regular file"),
        ("folder.bin", "folder.bin is not a regular file"),
        ("short.bin", "68 bytes declared, its source holds 50"),
        ("missing.bin", "missing.bin"),
        (
            "https://example.com/mesh.bin",
            "only files and data: URIs are read",
        ),
        (
            "data:application/octet-stream;base64,AAAA",
            "68 bytes declared, its source holds 3",
        ),
        ("data:text/plain,hello", "a data URI that is not base64"),
        ("bad%zzname.bin", "only files and data: URIs"),
    ] {
        let message = read_with_uri(&mut json, uri).unwrap_err().to_string();
        assert!(message.contains("mesh.gltf"), "{uri}: {message}");
        assert!(message.contains(expected), "{uri}: {message}");
    }
}

#[test]
fn bad_glb_is_refused_with_the_file_name() {
    let path = scratch("broken.glb");
    let mut bytes = glb();
    // Claim an index accessor of 40 elements: it runs out of its view.
    let needle = b"\"count\":3,\"type\":\"SCALAR\"";
    let at = bytes.windows(needle.len()).position(|w| w == needle).unwrap();
    bytes[at + 8] = b'9';
    std::fs::write(&path, &bytes).unwrap();
    let message = read_mesh(&path).unwrap_err().to_string();
    assert!(message.starts_with(&path.display().to_string()), "{message}");
    assert!(
        message.contains("the index accessor lies outside its buffer"),
        "{message}"
    );
    std::fs::write(&path, b"glTF garbage").unwrap();
    assert!(read_mesh(&path).is_err());
}

#[test]
fn files_round_trip_and_bad_paths_leave_nothing() {
    let mesh = parse_obj(SQUARE_OBJ).unwrap();
    for name in ["square.obj", "square.ply"] {
        let path = scratch(name);
        write_mesh(&path, &mesh).unwrap();
        let back = read_mesh(&path).unwrap();
        assert_eq!(back.positions(), mesh.positions());
        assert_eq!(corner_uvs(&back), corner_uvs(&mesh));
    }
    let bad = scratch("square.stl");
    let message = write_mesh(&bad, &mesh).unwrap_err().to_string();
    assert!(
        message.contains("square.stl") && message.contains("unknown mesh format"),
        "{message}"
    );
    assert!(!bad.exists());
    let missing = scratch("no-such-dir/square.obj");
    assert!(write_mesh(&missing, &mesh).is_err());
    assert!(!missing.exists());
    let message = read_mesh(&scratch("absent.ply")).unwrap_err().to_string();
    assert!(message.contains("absent.ply"), "{message}");
}

#[test]
#[ignore = "needs ../shared/data/ict-face (not part of the repository)"]
fn the_ict_scan_reads_like_tobj_reads_it() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-face/neutral_face.obj");
    let mesh = read_mesh(&path).unwrap();
    assert_eq!(mesh.positions().len(), 9409);
    assert_eq!(mesh.triangles().len(), 18460);
    assert!(mesh.texture().is_some());
    // tobj renumbers vertices, so compare triangles as coordinate triples.
    let (models, _) = tobj::load_obj(&path, &tobj::GPU_LOAD_OPTIONS).unwrap();
    let key = |p: [f64; 3]| p.map(f64::to_bits);
    let mut ours: Vec<_> = (0..mesh.triangles().len())
        .map(|k| mesh.triangle(k).map(|p| key([p.x, p.y, p.z])))
        .collect();
    let mut theirs = Vec::new();
    for model in &models {
        let m = &model.mesh;
        for t in m.indices.chunks_exact(3) {
            theirs.push([0, 1, 2].map(|c| {
                let i = 3 * t[c] as usize;
                // tobj reads f32; ours are f64 of the same decimal text.
                key([0, 1, 2].map(|a| f64::from(m.positions[i + a])))
            }));
        }
    }
    // Compare at f32 precision.
    let round = |v: &mut Vec<[[u64; 3]; 3]>| {
        for t in v.iter_mut() {
            for p in t.iter_mut() {
                *p = p.map(|b| f64::from(f64::from_bits(b) as f32).to_bits());
            }
        }
        v.sort_unstable();
    };
    round(&mut ours);
    round(&mut theirs);
    assert_eq!(ours, theirs);
}

/// Two overlapping planes: the front one wins; a tilted plane is interpolated exactly; samples
/// off the mesh are NaN.
#[test]
fn front_heights_keep_the_front_most_surface() {
    use splineface::mesh::{Raster, front_heights};
    let square = |z: [f64; 4], offset: u32| {
        (
            vec![
                Point3::new(0.0, 0.0, z[0]),
                Point3::new(4.0, 0.0, z[1]),
                Point3::new(4.0, 4.0, z[2]),
                Point3::new(0.0, 4.0, z[3]),
            ],
            vec![[offset, offset + 1, offset + 2], [offset, offset + 2, offset + 3]],
        )
    };
    // Back: the tilted plane z = 0.5x + 0.25y − 9; front: z = 0.5x + 0.25y (both planar).
    let plane = |x: f64, y: f64| 0.5 * x + 0.25 * y;
    let corners = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)];
    let (mut positions, mut triangles) = square(corners.map(|(x, y)| plane(x, y) - 9.0), 0);
    let (p2, t2) = square(corners.map(|(x, y)| plane(x, y)), 4);
    positions.extend(p2);
    triangles.extend(t2);
    let mesh = TriangleMesh::new(positions, triangles).unwrap();
    let raster = Raster {
        origin: Point2::new(-1.0, -1.0),
        spacing: 0.5,
        width: 13,
        height: 13,
    };
    let heights = front_heights(&mesh, &raster);
    let hits = splineface::mesh::front_hits(&mesh, &raster);
    for j in 0..raster.height {
        for i in 0..raster.width {
            let p = raster.position(i, j);
            let h = heights[j * raster.width + i];
            let hit = hits[j * raster.width + i];
            if (0.0..=4.0).contains(&p.x) && (0.0..=4.0).contains(&p.y) {
                assert!((h - plane(p.x, p.y)).abs() < 1e-12, "at {p}: {h}");
                // The hit is on the front square, and interpolating the vertex positions
                // there gives the sample's point.
                let hit = hit.unwrap();
                assert!(
                    hit.triangle >= 2,
                    "at {p}: the back square's triangle {}",
                    hit.triangle
                );
                let coords: Vec<_> = mesh.positions().iter().map(|v| v.coords).collect();
                let q = hit.interpolate(&mesh, &coords);
                assert!(
                    (q - Point3::new(p.x, p.y, h).coords).norm() < 1e-12,
                    "at {p}: {q}"
                );
            } else {
                assert!(h.is_nan(), "at {p}: {h}");
                assert!(hit.is_none());
            }
        }
    }
}

/// Found by fuzzing (`tools/fuzz`, target `glb`): a 95-byte GLB whose header claims gigabytes
/// made the `gltf` crate allocate them. It is now refused from the header.
#[test]
fn a_glb_header_claiming_gigabytes_is_refused_without_allocating() {
    let hex = "676c5446020000000000b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1b1803f676c0000";
    let bytes: Vec<u8> = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
        .collect();
    let path = std::env::temp_dir().join(format!("splineface-oom-{}.glb", std::process::id()));
    std::fs::write(&path, &bytes).unwrap();
    let error = splineface::mesh::read_mesh(&path).unwrap_err();
    assert!(error.to_string().contains("binary glTF"), "{error}");
    // A chunk longer than the file, with an honest total.
    let mut lying = b"glTF".to_vec();
    lying.extend(2u32.to_le_bytes());
    lying.extend(28u32.to_le_bytes());
    lying.extend(1_000_000u32.to_le_bytes());
    lying.extend(b"JSON");
    lying.extend(b"{}      ");
    std::fs::write(&path, &lying).unwrap();
    assert!(
        splineface::mesh::read_mesh(&path)
            .unwrap_err()
            .to_string()
            .contains("more than the file holds")
    );
    std::fs::remove_file(&path).unwrap();
}

/// Found by fuzzing (`tools/fuzz`, target `glb`), three times: 592-byte GLBs whose
/// primitive's POSITION names a missing accessor made the `gltf` crate's validation panic
/// (index out of bounds, gltf-json mesh.rs:151). They are now refused before that validation,
/// with an error naming the file, the primitive and the accessor (and no panic message on the
/// terminal). The third got past a first guard: its accessors' key is mangled and an unknown
/// key holds invalid UTF-8, which the gltf crate skips but a `serde_json::Value` refuses.
#[test]
fn glbs_that_panicked_the_gltf_crate_are_errors() {
    let files: [&[u8]; 3] = [
        include_bytes!("../data/fuzz-glb-validation-panic.glb"),
        include_bytes!("../data/fuzz-glb-validation-panic-2.glb"),
        include_bytes!("../data/fuzz-glb-validation-panic-3.glb"),
    ];
    for (k, bytes) in files.iter().enumerate() {
        let path = std::env::temp_dir().join(format!("splineface-panic-{k}-{}.glb", std::process::id()));
        std::fs::write(&path, bytes).unwrap();
        let error = splineface::mesh::read_mesh(&path).unwrap_err().to_string();
        assert!(error.starts_with(&path.display().to_string()), "{error}");
        let accessor = if k == 2 { 1 } else { 0 };
        assert!(
            error.contains(&format!(
                "mesh 0 primitive 0: POSITION names accessor {accessor}, and the file has 0"
            )),
            "{error}"
        );
        std::fs::remove_file(&path).unwrap();
    } // A repeated key keeps its last value, as the gltf crate reads it: the guard looks at 5.
    let repeated =
        br#"{"asset": {"version": "2.0"}, "accessors": [{"componentType": 5126, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "POSITION": 5}}]}]}"#;
    let error = splineface::mesh::parse_gltf(repeated, None)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("POSITION names accessor 5, and the file has 1"),
        "{error}"
    );
}
