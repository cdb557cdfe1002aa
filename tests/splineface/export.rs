//! Writers read back by independent readers: glTF by the `gltf` crate, OBJ by `tobj`, STEP by
//! steputils + geomdl (Python, an ignored test run by `.ci/run`).

use std::path::PathBuf;

use super::common::file_names;

use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::bspline::{StepOptions, encode_step};
use splineface::depth::{PhotoFit, Pose};
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::geometry::LengthUnit;
use splineface::io::encode_png;
use splineface::mesh::{PngTexture, write_glb, write_obj};
use splineface::mesh::{read_mesh, write_mesh};
use splineface::reference::ReferenceFace;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("splineface-export-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn face() -> FaceSurface {
    let r = ReferenceFace::embedded();
    FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap()
}

/// A photo fit seeing the face from slightly to the side, 4 px a unit, in a 640 × 480 photo.
fn photo_fit() -> PhotoFit {
    PhotoFit {
        name: "photo".into(),
        pose: Pose::from_yaw_pitch_roll_degrees(10.0, 5.0, 0.0, 2.0),
        rms_pixels: 0.0,
        rms_units: 0.0,
        inner_rms_units: 0.0,
        eye_midpoint: Point2::new(320.0, 200.0),
    }
}

fn texture_png() -> Vec<u8> {
    let image = image::RgbImage::from_fn(640, 480, |x, y| {
        image::Rgb([(x % 256) as u8, (y % 256) as u8, 128])
    });
    encode_png(&image).unwrap()
}

#[test]
fn glb_reads_back_with_the_gltf_crate() {
    let dir = scratch("glb");
    let clipped = face().mesh(&MeshOptions { spacing: 3.0 }).unwrap();
    let textured = clipped.photo_texture(&photo_fit(), 640, 480);
    let png = texture_png();
    for (name, mesh, texture) in [
        ("plain.glb", &clipped.mesh, None),
        ("textured.glb", &textured, Some(PngTexture { png: &png })),
    ] {
        let path = dir.join(name);
        write_glb(&path, mesh, "face", texture).unwrap();
        let (document, buffers, images) = gltf::import(&path).unwrap();
        let primitive = document.meshes().next().unwrap().primitives().next().unwrap();
        let reader = primitive.reader(|b| Some(&buffers[b.index()]));
        let positions: Vec<[f32; 3]> = reader.read_positions().unwrap().collect();
        let indices: Vec<u32> = reader.read_indices().unwrap().into_u32().collect();
        let normals: Vec<[f32; 3]> = reader.read_normals().unwrap().collect();
        assert_eq!(indices.len(), 3 * mesh.triangles().len());
        // Every output triangle is the input triangle, corner for corner.
        for (k, t) in mesh.triangles().iter().enumerate() {
            for c in 0..3 {
                let p = positions[indices[3 * k + c] as usize];
                let q = mesh.positions()[t[c] as usize];
                for d in 0..3 {
                    assert_eq!(p[d], q[d] as f32);
                }
                let n = normals[indices[3 * k + c] as usize];
                let m = mesh.normals().unwrap()[t[c] as usize];
                assert!((n[0] - m.x as f32).abs() < 1e-6 && (n[2] - m.z as f32).abs() < 1e-6);
            }
        }
        match texture {
            None => {
                assert!(reader.read_tex_coords(0).is_none());
                assert!(images.is_empty());
            }
            Some(_) => {
                let uvs: Vec<[f32; 2]> = reader.read_tex_coords(0).unwrap().into_f32().collect();
                let source = mesh.texture().unwrap();
                for (k, t) in source.triangles.iter().enumerate() {
                    for c in 0..3 {
                        let uv = uvs[indices[3 * k + c] as usize];
                        let want = source.uvs[t[c] as usize];
                        assert!((uv[0] - want.x as f32).abs() < 1e-6);
                        assert!((uv[1] - (1.0 - want.y) as f32).abs() < 1e-6, "glTF's v runs down");
                    }
                }
                assert_eq!((images[0].width, images[0].height), (640, 480));
                let material = primitive.material();
                assert!(material.pbr_metallic_roughness().base_color_texture().is_some());
            }
        }
    }
    // Our own reader agrees on the geometry.
    let back = read_mesh(&dir.join("plain.glb")).unwrap();
    assert_eq!(back.triangles().len(), clipped.mesh.triangles().len());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn textured_obj_reads_back_with_tobj() {
    let dir = scratch("obj");
    let clipped = face().mesh(&MeshOptions { spacing: 3.0 }).unwrap();
    let textured = clipped.photo_texture(&photo_fit(), 640, 480);
    let path = dir.join("face.obj");
    write_obj(&path, &textured, Some(&texture_png())).unwrap();
    assert!(dir.join("face.mtl").is_file() && dir.join("face.png").is_file());
    let (models, materials) = tobj::load_obj(&path, &tobj::GPU_LOAD_OPTIONS).unwrap();
    let materials = materials.unwrap();
    assert_eq!(materials[0].diffuse_texture.as_deref(), Some("face.png"));
    let model = &models[0].mesh;
    assert_eq!(model.indices.len(), 3 * textured.triangles().len());
    assert_eq!(model.material_id, Some(0));
    // Single-index loading pairs every position with its coordinate and normal.
    let source = textured.texture().unwrap();
    for (k, t) in textured.triangles().iter().enumerate() {
        for c in 0..3 {
            let i = model.indices[3 * k + c] as usize;
            let p = textured.positions()[t[c] as usize];
            let uv = source.uvs[source.triangles[k][c] as usize];
            let n = textured.normals().unwrap()[t[c] as usize];
            assert_eq!(model.positions[3 * i] as Real, p.x as f32 as Real);
            assert_eq!(model.texcoords[2 * i + 1], uv.y as f32);
            assert_eq!(model.normals[3 * i + 2], n.z as f32);
        }
    }
    // The texture coordinates are where the pose sees each vertex.
    let fit = photo_fit();
    for (k, p) in textured.positions().iter().enumerate().step_by(50) {
        let q = fit.pixel(p);
        let uv = source.uvs[k];
        assert!((uv.x * 640.0 - q.x).abs() < 1e-9 && ((1.0 - uv.y) * 480.0 - q.y).abs() < 1e-9);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn writers_leave_nothing_behind_on_failure() {
    let dir = scratch("fail");
    let clipped = face().mesh(&MeshOptions { spacing: 4.0 }).unwrap();
    let textured = clipped.photo_texture(&photo_fit(), 640, 480);
    let missing = dir.join("no-such-dir").join("face.obj");
    let error = write_obj(&missing, &textured, Some(&texture_png())).unwrap_err();
    assert!(error.to_string().contains("no-such-dir"), "{error}");
    // The OBJ itself is unwritable (a directory is in the way): the texture and MTL written
    // before it are removed again.
    std::fs::create_dir(dir.join("face.obj")).unwrap();
    assert!(write_obj(&dir.join("face.obj"), &textured, Some(&texture_png())).is_err());
    assert!(!dir.join("face.png").exists() && !dir.join("face.mtl").exists());
    assert!(write_glb(&missing.with_extension("glb"), &clipped.mesh, "face", None).is_err());
    assert_eq!(file_names(&dir), ["face.obj"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn ply_and_obj_carry_normals() {
    let dir = scratch("normals");
    let clipped = face().mesh(&MeshOptions { spacing: 4.0 }).unwrap();
    for name in ["face.ply", "face.obj"] {
        let path = dir.join(name);
        write_mesh(&path, &clipped.mesh).unwrap();
        let back = read_mesh(&path).unwrap();
        assert_eq!(back.positions(), clipped.mesh.positions());
        assert_eq!(back.triangles(), clipped.mesh.triangles());
    }
    let header = std::fs::read(dir.join("face.ply")).unwrap();
    let header = String::from_utf8_lossy(&header[..400]);
    assert!(header.contains("property double nx"));
    let (models, _) = tobj::load_obj(dir.join("face.obj"), &tobj::GPU_LOAD_OPTIONS).unwrap();
    assert_eq!(models[0].mesh.normals.len(), 3 * clipped.mesh.positions().len());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The file declares the unit it is asked to (millimetres unless told), as STEP's SI unit of
/// length with its prefix, and the numbers are the same whatever it declares.
#[test]
fn step_files_declare_their_unit() {
    let face = face();
    let text = |unit: Option<LengthUnit>| {
        let base = StepOptions {
            name: "face",
            description: "canonical units",
            ..StepOptions::default()
        };
        let options = match unit {
            Some(unit) => StepOptions { unit, ..base },
            None => base,
        };
        encode_step(face.surface(), &options).unwrap()
    };
    let declared = |text: &str| {
        let at = text.find("SI_UNIT(").unwrap();
        text[at..at + text[at..].find(')').unwrap() + 1].to_owned()
    };
    assert_eq!(declared(&text(None)), "SI_UNIT(.MILLI.,.METRE.)");
    for (unit, expected) in [
        (LengthUnit::Millimetre, "SI_UNIT(.MILLI.,.METRE.)"),
        (LengthUnit::Centimetre, "SI_UNIT(.CENTI.,.METRE.)"),
        (LengthUnit::Metre, "SI_UNIT($,.METRE.)"),
    ] {
        let file = text(Some(unit));
        assert_eq!(declared(&file), expected);
        assert_eq!(
            file.replace(expected, ""),
            text(None).replace("SI_UNIT(.MILLI.,.METRE.)", "")
        );
    }
}

fn step_file(trim: bool) -> (String, FaceSurface) {
    let face = face();
    let text = encode_step(
        face.surface(),
        &StepOptions {
            name: "face",
            description: "canonical units",
            unit: LengthUnit::Metre,
            trim: if trim { face.clip() } else { &[] },
        },
    )
    .unwrap();
    (text, face)
}

/// The data section's entities, checked to be numbered from 1 in order and to refer only to
/// entities before them.
fn step_entities(text: &str) -> Vec<&str> {
    assert!(text.starts_with("ISO-10303-21;\nHEADER;"));
    assert!(text.trim_end().ends_with("END-ISO-10303-21;"));
    let data = &text[text.find("DATA;").unwrap() + 6..text.rfind("ENDSEC;").unwrap()];
    let lines: Vec<&str> = data.lines().collect();
    for (k, line) in lines.iter().enumerate() {
        assert!(
            line.starts_with(&format!("#{}=", k + 1)) && line.ends_with(';'),
            "{line}"
        );
        for part in line.split('#').skip(2) {
            let n: usize = part
                .chars()
                .take_while(char::is_ascii_digit)
                .collect::<String>()
                .parse()
                .unwrap();
            assert!(n >= 1 && n <= k + 1, "{line}");
        }
    }
    lines
}

fn count(lines: &[&str], entity: &str) -> usize {
    lines
        .iter()
        .filter(|l| l.contains(&format!("={entity}(")) || l.contains(&format!("({entity}(")))
        .count()
}

#[test]
fn an_untrimmed_step_file_is_the_surface_alone() {
    let (text, face) = step_file(false);
    let lines = step_entities(&text);
    let grid = face.surface().rows() * face.surface().cols();
    assert_eq!(count(&lines, "CARTESIAN_POINT"), grid);
    assert_eq!(count(&lines, "B_SPLINE_SURFACE_WITH_KNOTS"), 1);
    assert_eq!(
        count(&lines, "GEOMETRICALLY_BOUNDED_SURFACE_SHAPE_REPRESENTATION"),
        1
    );
    assert_eq!(count(&lines, "ADVANCED_FACE"), 0);
}

#[test]
fn a_trimmed_step_file_bounds_one_face_by_the_clip_polygon() {
    let (text, face) = step_file(true);
    let lines = step_entities(&text);
    let one = [
        "B_SPLINE_SURFACE_WITH_KNOTS",
        "ADVANCED_FACE",
        "FACE_OUTER_BOUND",
        "EDGE_LOOP",
        "EDGE_CURVE",
        "SURFACE_CURVE",
        "PCURVE",
        "OPEN_SHELL",
        "SHELL_BASED_SURFACE_MODEL",
        "MANIFOLD_SURFACE_SHAPE_REPRESENTATION",
    ];
    for entity in one {
        assert_eq!(count(&lines, entity), 1, "{entity}");
    }
    assert_eq!(count(&lines, "B_SPLINE_CURVE_WITH_KNOTS"), 2);
    // The parameter-space curve: the clip's vertices, closed, counter-clockwise.
    let uv_curve = lines
        .iter()
        .find(|l| l.contains("B_SPLINE_CURVE_WITH_KNOTS('',1,"))
        .unwrap();
    let refs = uv_curve.matches('#').count() - 1;
    assert_eq!(refs, face.clip().len() + 1);
    // The space curve has the degree of the image of a line on a bicubic patch.
    let degree = face.surface().degree_u() + face.surface().degree_v();
    assert!(
        lines
            .iter()
            .any(|l| l.contains(&format!("B_SPLINE_CURVE_WITH_KNOTS('',{degree},")))
    );
    let grid = face.surface().rows() * face.surface().cols();
    let points = count(&lines, "CARTESIAN_POINT");
    // Grid, space curve (several Bézier pieces a side), polygon, vertex, origin.
    assert!(points > grid + 2 * face.clip().len() + 2, "{points}");
}

#[test]
fn a_trim_that_is_not_a_polygon_in_the_domain_is_refused() {
    let face = face();
    for (trim, what) in [
        (vec![Point2::new(0.2, 0.2), Point2::new(0.8, 0.2)], "too short"),
        (
            vec![
                Point2::new(0.2, 0.2),
                Point2::new(1.8, 0.2),
                Point2::new(0.5, 0.9),
            ],
            "outside",
        ),
        (
            vec![
                Point2::new(0.2, 0.2),
                Point2::new(0.4, 0.3),
                Point2::new(0.6, 0.4),
            ],
            "collinear",
        ),
    ] {
        let result = encode_step(
            face.surface(),
            &StepOptions {
                name: "face",
                trim: &trim,
                ..StepOptions::default()
            },
        );
        match what {
            "too short" => assert_eq!(
                result.unwrap_err(),
                splineface::bspline::BSplineError::PolylineTooShort {
                    distinct: 2,
                    needed: 3
                }
            ),
            "collinear" => assert_eq!(
                result.unwrap_err(),
                splineface::bspline::BSplineError::DegenerateTrim
            ),
            _ => assert!(result.is_err(), "{what}"),
        }
    }
}

/// Reads the STEP file back with steputils and evaluates it with geomdl (both Python,
/// independent of this crate). `.ci/run` installs them: `pip install steputils geomdl`.
#[test]
#[ignore = "needs python3 with steputils and geomdl (installed by .ci/run)"]
fn step_reads_back_with_an_independent_reader() {
    let dir = scratch("step");
    let (text, face) = step_file(true);
    let path = dir.join("face.step");
    std::fs::write(&path, text).unwrap();
    let params: Vec<[Real; 2]> = (0..50)
        .map(|k| [((k * 7) % 50) as Real / 49.0, (k as Real / 49.0).powi(2)])
        .collect();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tools/check_step.py");
    let mut child = std::process::Command::new("python3")
        .arg(script)
        .arg(&path)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    use std::io::Write;
    child
        .stdin
        .take()
        .unwrap()
        .write_all(serde_json::to_string(&params).unwrap().as_bytes())
        .unwrap();
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let read: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let points: Vec<[Real; 3]> = serde_json::from_value(read["points"].clone()).unwrap();
    assert_eq!(points.len(), params.len());
    for (p, q) in params.iter().zip(&points) {
        let ours = face.surface().eval(p[0], p[1]).unwrap();
        let d = (ours - Point3::from(*q)).norm();
        assert!(d < 1e-9, "at {p:?}: {d}");
    }
    // The trimmed face's edge: its space curve is the surface along its parameter-space curve
    // (both as geomdl evaluates them), and that curve is the clip polygon, counter-clockwise.
    let trim = &read["trim"];
    let gap = trim["gap"].as_f64().unwrap();
    assert!(gap < 1e-9, "the edge's two curves are {gap} apart");
    assert_eq!(trim["vertices"].as_u64().unwrap() as usize, face.clip().len());
    let area = splineface::geometry::signed_area(face.clip()).abs();
    let read_area = trim["area"].as_f64().unwrap();
    assert!(
        read_area > 0.0 && (read_area - area).abs() < 1e-12,
        "{read_area} against {area}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A set of files is written all or nothing, the files staged side by side: when two of them
/// cannot be staged (a file stands where their folder would be), the first in the set's order is
/// named, and neither the others nor any temporary is left; otherwise every file holds its bytes
/// and no temporary is left.
#[test]
fn a_set_of_files_is_written_all_or_nothing() {
    let dir = scratch("set");
    std::fs::write(dir.join("blocker"), b"a file, not a folder").unwrap();
    let file = |name: &str| (dir.join(name), name.as_bytes().repeat(1000));
    let mut files: Vec<(PathBuf, Vec<u8>)> = (0..24).map(|k| file(&format!("f{k}.bin"))).collect();
    files.insert(9, file("blocker/first.bin"));
    files.insert(17, file("blocker/second.bin"));
    let (path, _) = splineface::io::write_files_atomically(&files).unwrap_err();
    assert_eq!(path, dir.join("blocker/first.bin"));
    assert_eq!(file_names(&dir), ["blocker"]);
    files.retain(|(p, _)| !p.starts_with(dir.join("blocker")));
    splineface::io::write_files_atomically(&files).unwrap();
    for (path, bytes) in &files {
        assert_eq!(&std::fs::read(path).unwrap(), bytes);
    }
    assert_eq!(file_names(&dir).len(), files.len() + 1, "{:?}", file_names(&dir));
    std::fs::remove_dir_all(&dir).unwrap();
}
