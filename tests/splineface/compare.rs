//! Comparing reconstructions with the truth: alignment recovered, known errors measured, the
//! `compare` and `render-depth` commands.

use super::common::{scratch, splineface};
use std::path::PathBuf;

use nalgebra::{Point3, Similarity3, Translation3, UnitQuaternion, Vector3};
use splineface::Real;
use splineface::compare::{
    CompareError, CompareOptions, InnerFaceOptions, LengthUnit, MeshFiles, compare, compare_files,
    fit_similarity, inner_face_score,
};
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::mesh::{TriangleMesh, write_mesh};
use splineface::reference::ReferenceFace;

/// The embedded reference face as a mesh in millimetres, with its structure.
fn truth() -> (TriangleMesh, Vec<Point3<Real>>) {
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let mm = 63.0 / 50.0;
    let mesh = face.mesh(&MeshOptions { spacing: 1.5 }).unwrap().mesh;
    let scale = nalgebra::Affine3::from_matrix_unchecked(nalgebra::Matrix4::new_nonuniform_scaling(
        &Vector3::repeat(mm),
    ));
    (
        mesh.transformed(&scale),
        r.structure().iter().map(|p| p * mm).collect(),
    )
}

fn similarity() -> Similarity3<Real> {
    Similarity3::from_parts(
        Translation3::new(12.0, -4.0, 30.0),
        UnitQuaternion::from_euler_angles(0.1, -0.3, 0.05),
        0.8,
    )
}

#[test]
fn umeyama_recovers_a_similarity() {
    let (_, structure) = truth();
    let s = similarity();
    let moved: Vec<Point3<Real>> = structure.iter().map(|p| s * p).collect();
    let (found, rms) = fit_similarity(&structure, &moved).unwrap();
    assert!(rms < 1e-9);
    assert!((found.to_homogeneous() - s.to_homogeneous()).norm() < 1e-9);
    let line: Vec<Point3<Real>> = (0..40).map(|k| Point3::new(k as Real, 0.0, 0.0)).collect();
    assert!(fit_similarity(&line, &line).is_none());
}

/// The truth and its structure, and both moved by [`similarity`].
fn truth_and_moved() -> (TriangleMesh, Vec<Point3<Real>>, TriangleMesh, Vec<Point3<Real>>) {
    let (mesh, structure) = truth();
    let s = similarity();
    let moved = mesh.transformed(&nalgebra::Affine3::from_matrix_unchecked(s.to_homogeneous()));
    let moved_structure: Vec<Point3<Real>> = structure.iter().map(|p| s * p).collect();
    (mesh, structure, moved, moved_structure)
}

#[test]
fn the_same_face_moved_compares_as_identical() {
    let (mesh, structure, moved, moved_structure) = truth_and_moved();
    let result = compare(
        &moved,
        &mesh,
        Some((&moved_structure, &structure)),
        &CompareOptions::default(),
    )
    .unwrap();
    let stats = &result.stats;
    assert!(
        (stats.alignment.scale - 1.25).abs() < 1e-9,
        "{}",
        stats.alignment.scale
    );
    assert!(stats.depth_error.max < 1e-6, "{:?}", stats.depth_error);
    assert!(stats.point_to_surface.max < 1e-9, "{:?}", stats.point_to_surface);
    assert!((stats.paper.structure_ssim.unwrap() - 1.0).abs() < 1e-9);
    assert!((stats.paper.depth_correlation.unwrap() - 1.0).abs() < 1e-9);
    assert!(stats.pixels_compared > 100_000);
}

#[test]
fn the_inner_face_keeps_the_truths_heights_where_it_scores() {
    // The same face moved: once aligned it lies on the truth, so its front heights are the
    // truth's at every sample of the inner face, and the truth's heights are NaN exactly where
    // no distance was scored.
    let (mesh, structure, moved, moved_structure) = truth_and_moved();
    let c = inner_face_score(
        &moved,
        &mesh,
        (&moved_structure, &structure),
        &InnerFaceOptions::default(),
    )
    .unwrap();
    let front = splineface::mesh::front_heights(&c.aligned, &c.raster);
    assert_eq!(c.truth_heights.len(), c.raster.width * c.raster.height);
    let mut scored = 0;
    for ((t, d), f) in c.truth_heights.iter().zip(&c.distances).zip(&front) {
        assert_eq!(t.is_nan(), d.is_nan());
        if t.is_finite() {
            scored += 1;
            assert!((f - t).abs() < 1e-6, "front {f} against the truth's {t}");
        }
    }
    assert!(scored > 1000, "{scored} samples");
    // Moved 1 mm toward the viewer along the truth's view axis, it lies in front everywhere.
    let toward = c.aligned.transformed(&nalgebra::Affine3::from_matrix_unchecked(
        nalgebra::Translation3::new(0.0, 0.0, 1.0).to_homogeneous(),
    ));
    let front = splineface::mesh::front_heights(&toward, &c.raster);
    for (t, f) in c.truth_heights.iter().zip(&front) {
        if t.is_finite() && f.is_finite() {
            assert!(
                (f - t - 1.0).abs() < 1e-6,
                "front {f} against the truth's {t} + 1"
            );
        }
    }
}

#[test]
fn a_known_offset_is_measured() {
    // The reconstruction stands 1.5 mm in front of the truth everywhere; the structures agree.
    let (mesh, structure) = truth();
    let shifted = TriangleMesh::new(
        mesh.positions()
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 1.5))
            .collect(),
        mesh.triangles().to_vec(),
    )
    .unwrap();
    let result = compare(
        &shifted,
        &mesh,
        Some((&structure, &structure)),
        &CompareOptions::default(),
    )
    .unwrap();
    let stats = &result.stats;
    assert!((stats.depth_error.mean - 1.5).abs() < 1e-9 && (stats.depth_error.max - 1.5).abs() < 1e-9);
    assert!((stats.mean_signed_dz - 1.5).abs() < 1e-9);
    let eyes = 63.0;
    assert!((stats.paper.mean_abs_dz_over_eye_distance - 1.5 / eyes).abs() < 1e-9);
    // Every vertex is at most 1.5 mm from the truth, most of them less (the surface slopes).
    assert!(stats.point_to_surface.max <= 1.5 + 1e-3 && stats.point_to_surface.mean > 0.3);
}

#[test]
fn icp_aligns_without_structures() {
    let (mesh, _) = truth();
    let turn = Similarity3::from_parts(
        Translation3::new(2.0, -1.0, 1.5),
        UnitQuaternion::from_euler_angles(0.03, -0.04, 0.02),
        1.0,
    );
    let moved = mesh.transformed(&nalgebra::Affine3::from_matrix_unchecked(turn.to_homogeneous()));
    let result = compare(&moved, &mesh, None, &CompareOptions::default()).unwrap();
    let stats = &result.stats;
    assert_eq!(stats.alignment.method, "icp (rigid)");
    assert!(
        stats.depth_error.mean < 0.01,
        "{:?} {:?}",
        stats.depth_error,
        stats.alignment
    );
    assert!(stats.alignment.iterations < 30, "{:?}", stats.alignment);
    assert!(stats.point_to_surface.p90 < 0.01, "{:?}", stats.point_to_surface);
}

#[test]
fn bad_comparisons_are_errors() {
    let (mesh, structure) = truth();
    let short = &structure[..30];
    assert!(matches!(
        compare(
            &mesh,
            &mesh,
            Some((short, &structure)),
            &CompareOptions::default()
        ),
        Err(CompareError::Structure {
            which: "reconstruction",
            ..
        })
    ));
    let far = mesh.transformed(&nalgebra::Affine3::from_matrix_unchecked(
        Similarity3::from_parts(Translation3::new(1e4, 0.0, 0.0), UnitQuaternion::identity(), 1.0)
            .to_homogeneous(),
    ));
    // Aligned by (unmoved) structures, the far mesh does not overlap the truth.
    assert_eq!(
        compare(
            &far,
            &mesh,
            Some((&structure, &structure)),
            &CompareOptions::default()
        )
        .unwrap_err(),
        CompareError::NoOverlap
    );
    for size in [0, 8, 100_000] {
        let options = CompareOptions {
            size,
            ..CompareOptions::default()
        };
        assert!(matches!(
            compare(&mesh, &mesh, None, &options),
            Err(CompareError::Option { .. })
        ));
    }
}

fn landmarks_json(points: &[Point3<Real>]) -> String {
    let points: Vec<Vec<Real>> = points.iter().map(|p| vec![p.x, p.y, p.z]).collect();
    serde_json::json!({ "format": "splineface/landmarks", "version": 1, "scheme": "structure40", "points": points })
        .to_string()
}

#[test]
fn the_commands_write_their_files_and_refuse_bad_input() {
    let dir = scratch("compare", "cli");
    let (mesh, structure) = truth();
    let truth_path = dir.join("truth.ply");
    // The truth in centimetres, the reconstruction in millimetres 1 mm in front.
    let cm = nalgebra::Affine3::from_matrix_unchecked(nalgebra::Matrix4::new_nonuniform_scaling(
        &Vector3::repeat(0.1),
    ));
    write_mesh(&truth_path, &mesh.transformed(&cm)).unwrap();
    let rec_path = dir.join("rec.obj");
    let shifted = TriangleMesh::new(
        mesh.positions()
            .iter()
            .map(|p| p + Vector3::new(0.0, 0.0, 1.0))
            .collect(),
        mesh.triangles().to_vec(),
    )
    .unwrap();
    write_mesh(&rec_path, &shifted).unwrap();
    std::fs::write(dir.join("rec.json"), landmarks_json(&structure)).unwrap();
    let in_cm: Vec<Point3<Real>> = structure.iter().map(|p| p * 0.1).collect();
    std::fs::write(dir.join("truth.json"), landmarks_json(&in_cm)).unwrap();
    let s = |p: PathBuf| p.to_str().unwrap().to_owned();
    let out = dir.join("out");
    let run = splineface(&[
        "compare",
        &s(rec_path.clone()),
        &s(truth_path.clone()),
        "--out",
        &s(out.clone()),
        "--reconstruction-landmarks",
        &s(dir.join("rec.json")),
        "--truth-landmarks",
        &s(dir.join("truth.json")),
        "--truth-units",
        "cm",
        "--size",
        "256",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stats: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stats.json")).unwrap()).unwrap();
    let mean = stats["depth_error"]["mean"].as_f64().unwrap();
    assert!((mean - 1.0).abs() < 1e-6, "{mean}");
    for file in [
        "heatmap.png",
        "reconstruction-depth.exr",
        "truth-depth.exr",
        "reconstruction.png",
        "truth.png",
    ] {
        assert!(out.join(file).is_file(), "{file}");
    }

    // render-depth: EXR, PNG and a preview.
    for name in ["d.exr", "d.png"] {
        let target = dir.join(name);
        let run = splineface(&[
            "render-depth",
            &s(truth_path.clone()),
            "--out",
            &s(target.clone()),
            "--size",
            "96x64",
            "--view",
            "20,-10,0",
            "--preview",
            &s(dir.join("preview.png")),
        ]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        assert!(target.is_file());
    }
    let preview = image::open(dir.join("preview.png")).unwrap();
    assert_eq!((preview.width(), preview.height()), (96, 64));

    // Bad input: a message naming the problem, exit code 1, nothing written.
    let missing = s(dir.join("missing.ply"));
    let bad_out = s(dir.join("bad.exr"));
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "render-depth".into(),
                missing.clone(),
                "--out".into(),
                bad_out.clone(),
            ],
            "missing.ply",
        ),
        (
            vec![
                "render-depth".into(),
                s(truth_path.clone()),
                "--out".into(),
                s(dir.join("bad.tiff")),
            ],
            "must be .exr or .png",
        ),
        (
            vec![
                "render-depth".into(),
                s(truth_path.clone()),
                "--out".into(),
                bad_out.clone(),
                "--size".into(),
                "0".into(),
            ],
            "--size",
        ),
        (
            vec![
                "render-depth".into(),
                s(truth_path.clone()),
                "--out".into(),
                bad_out.clone(),
                "--view".into(),
                "side".into(),
            ],
            "--view",
        ),
        (
            vec![
                "render-depth".into(),
                s(truth_path.clone()),
                "--out".into(),
                s(dir.join("nodir").join("x.exr")),
            ],
            "nodir",
        ),
        (
            vec![
                "compare".into(),
                s(rec_path.clone()),
                missing.clone(),
                "--out".into(),
                s(dir.join("o2")),
            ],
            "missing.ply",
        ),
        (
            vec![
                "compare".into(),
                s(rec_path.clone()),
                s(truth_path.clone()),
                "--out".into(),
                s(dir.join("o3")),
                "--truth-units".into(),
                "inches".into(),
            ],
            "--truth-units",
        ),
        (
            vec![
                "compare".into(),
                s(rec_path.clone()),
                s(truth_path.clone()),
                "--out".into(),
                s(truth_path.clone()),
            ],
            "not a directory",
        ),
    ];
    for (args, message) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let run = splineface(&args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{args:?}: {stderr}");
        assert!(stderr.contains(message), "{args:?}: {stderr}");
    }
    assert!(!dir.join("bad.exr").exists() && !dir.join("o2").exists() && !dir.join("o3").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A coarse mesh of a face scored against a fine mesh of the same surface: over the inner face
/// the truth's samples lie on the surface to the fine mesh's chord error, so their distances to
/// the exact surface (point inversion, `--reconstruction-surface`) are a small fraction of
/// those to the coarse mesh, whose flat triangles cut under the curved face. The surface is
/// given in centimetres like its mesh, and scaled with it. A bad surface file is named.
#[test]
fn the_inner_face_is_scored_against_the_exact_surface() {
    let dir = scratch("compare", "surface");
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let (mm, cm) = (63.0 / 50.0, 63.0 / 500.0);
    let scaled = |s: Real| {
        nalgebra::Affine3::from_matrix_unchecked(nalgebra::Matrix4::new_nonuniform_scaling(&Vector3::repeat(
            s,
        )))
    };
    let fine = face.mesh(&MeshOptions { spacing: 0.75 }).unwrap().mesh;
    let coarse = face.mesh(&MeshOptions { spacing: 6.0 }).unwrap().mesh;
    write_mesh(&dir.join("truth.ply"), &fine.transformed(&scaled(mm))).unwrap();
    write_mesh(&dir.join("coarse.ply"), &coarse.transformed(&scaled(cm))).unwrap();
    std::fs::write(
        dir.join("surface.json"),
        face.surface().transformed(&scaled(cm)).to_json(),
    )
    .unwrap();
    let structure = |s: Real| landmarks_json(&r.structure().iter().map(|p| p * s).collect::<Vec<_>>());
    std::fs::write(dir.join("truth.json"), structure(mm)).unwrap();
    std::fs::write(dir.join("coarse.json"), structure(cm)).unwrap();
    let files = MeshFiles {
        reconstruction: dir.join("coarse.ply"),
        truth: dir.join("truth.ply"),
        landmarks: Some((dir.join("coarse.json"), dir.join("truth.json"))),
        units: (LengthUnit::Centimetre, LengthUnit::Millimetre),
        surface: Some(dir.join("surface.json")),
    };
    let result = compare_files(&files, &CompareOptions::default()).unwrap();
    let to_mesh = result.comparison.stats.inner_face.unwrap().distance;
    let to_surface = result.inner_face_surface.unwrap().distance;
    assert!(to_surface.mean < 0.01, "to the surface: {to_surface:?}");
    assert!(
        to_mesh.mean > 5.0 * to_surface.mean,
        "to the mesh: {to_mesh:?}, to the surface: {to_surface:?}"
    );
    // Without the landmarks there is no inner face to score, with or without the surface.
    let result = compare_files(
        &MeshFiles {
            landmarks: None,
            ..files.clone()
        },
        &CompareOptions::default(),
    )
    .unwrap();
    assert!(result.inner_face_surface.is_none());

    std::fs::write(dir.join("bad.json"), "{\"format\": \"something else\"}").unwrap();
    let error = compare_files(
        &MeshFiles {
            surface: Some(dir.join("bad.json")),
            ..files
        },
        &CompareOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(error, splineface::Error::SurfaceFile(_)), "{error}");
    assert!(
        error.to_string().contains("bad.json: not a splineface surface"),
        "{error}"
    );
}
