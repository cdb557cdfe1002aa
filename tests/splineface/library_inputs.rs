//! The library's own checks of what front ends hand it (the command line and the Python
//! package only format these errors): the comparison of mesh files, scans' landmark files,
//! face-space mode files, output paths, the demo's settings and the mean-face baseline.

use super::common::scratch;

use nalgebra::{Point3, Similarity3, Vector3};
use splineface::Real;
use splineface::compare::{CompareOptions, LengthUnit, MeshFiles, compare_files};
use splineface::face::modes::{ModeFileProblem, read_displacement_fields};
use splineface::face::{MeanFace, MeshOptions, Units};
use splineface::io::{OutputError, check_output_file};
use splineface::landmarks::{LandmarkProblem, read_mesh_landmarks, read_mesh_structure};
use splineface::mesh::{PlyEncoding, TriangleMesh, encode_ply};
use splineface::reference::ReferenceFace;

/// The embedded mean face in millimetres, written as PLY into `dir` in `unit`s, with its
/// structure's 68-point landmark file as 3D JSON.
fn mean_face_files(dir: &std::path::Path, name: &str, unit: Real) -> (std::path::PathBuf, Vec<Point3<Real>>) {
    let mean = MeanFace::new(
        ReferenceFace::embedded(),
        Units::default(),
        &MeshOptions { spacing: 1.5 },
    )
    .unwrap();
    let scale = nalgebra::Affine3::from_matrix_unchecked(nalgebra::Matrix4::new_scaling(1.0 / unit));
    let path = dir.join(format!("{name}.ply"));
    std::fs::write(
        &path,
        encode_ply(&mean.mesh.transformed(&scale), PlyEncoding::Ascii),
    )
    .unwrap();
    (path, mean.photo_structure)
}

#[test]
fn compare_files_checks_its_options_before_reading_anything() {
    let files = MeshFiles {
        reconstruction: "/nowhere/a.obj".into(),
        truth: "/nowhere/b.obj".into(),
        landmarks: None,
        units: (LengthUnit::Millimetre, LengthUnit::Millimetre),
        surface: None,
    };
    let error = compare_files(
        &files,
        &CompareOptions {
            heatmap_max: Some(-1.0),
            ..CompareOptions::default()
        },
    )
    .unwrap_err();
    match error {
        splineface::Error::Setting(e) => {
            assert_eq!(
                e.flag_message(),
                "--max -1: must be a positive number of millimetres"
            )
        }
        other => panic!("{other}"),
    }
    // Good options: the missing file is named.
    let error = compare_files(&files, &CompareOptions::default()).unwrap_err();
    assert!(matches!(error, splineface::Error::Mesh(_)), "{error}");
    assert!(error.to_string().starts_with("/nowhere/a.obj:"), "{error}");
}

#[test]
fn compare_files_scales_by_the_units_and_scores_the_mean_face() {
    let dir = scratch("library-inputs", "units");
    // The same face written in mm and in cm: after scaling they are one surface.
    let (mm, _) = mean_face_files(&dir, "mm", 1.0);
    let (cm, _) = mean_face_files(&dir, "cm", 10.0);
    let files = MeshFiles {
        reconstruction: mm.clone(),
        truth: cm.clone(),
        landmarks: None,
        units: (LengthUnit::Millimetre, LengthUnit::Centimetre),
        surface: None,
    };
    let result = compare_files(&files, &CompareOptions::default()).unwrap();
    assert!(
        result.comparison.stats.depth_error.mean < 1e-3,
        "{:?}",
        result.comparison.stats.depth_error
    );
    assert!(result.mean_face.is_none(), "no landmarks, no inner-face score");
    // Read as millimetres the truth is a tenth of the size: the comparison sees it.
    let wrong = compare_files(
        &MeshFiles {
            units: (LengthUnit::Millimetre, LengthUnit::Millimetre),
            ..files
        },
        &CompareOptions::default(),
    );
    assert!(wrong.map_or(true, |r| r.comparison.stats.depth_error.mean > 1.0));
    assert_eq!(LengthUnit::parse("CM"), Some(LengthUnit::Centimetre));
    assert_eq!(LengthUnit::parse("furlong"), None);
    assert_eq!(LengthUnit::Metre.millimetres(), 1000.0);
}

#[test]
fn a_comparison_writes_its_files_with_the_extra_figures() {
    let dir = scratch("library-inputs", "files");
    let (a, _) = mean_face_files(&dir, "a", 1.0);
    let files = MeshFiles {
        reconstruction: a.clone(),
        truth: a,
        landmarks: None,
        units: (LengthUnit::Millimetre, LengthUnit::Millimetre),
        surface: None,
    };
    let result = compare_files(&files, &CompareOptions::default()).unwrap();
    let mut extra = serde_json::Map::new();
    extra.insert("units".into(), "mm".into());
    let written = result.comparison.files(extra.clone(), true).unwrap();
    let names: Vec<_> = written
        .iter()
        .map(|(p, _)| p.to_str().unwrap().to_owned())
        .collect();
    assert_eq!(
        names,
        [
            "heatmap.png",
            "reconstruction-depth.exr",
            "truth-depth.exr",
            "reconstruction.png",
            "truth.png",
            "stats.json"
        ]
    );
    let stats: serde_json::Value = serde_json::from_slice(&written[5].1).unwrap();
    assert_eq!(stats["units"], "mm");
    assert_eq!(stats["pixels_compared"], result.comparison.stats.pixels_compared);
    let without = result.comparison.files(extra, false).unwrap();
    assert_eq!(without.len(), 4);
}

#[test]
fn a_scans_landmark_file_is_read_as_3d_json_or_vertex_indices() {
    let dir = scratch("library-inputs", "structure");
    let mesh = TriangleMesh::new(
        (0..70)
            .map(|k| Point3::new(k as Real, (k * k % 7) as Real, (k % 3) as Real))
            .collect(),
        vec![[0, 1, 2]],
    )
    .unwrap();
    // 68 indices: the structure is derived from those vertices.
    let indices = dir.join("landmarks.txt");
    std::fs::write(&indices, (0..68).map(|k| format!("{k}\n")).collect::<String>()).unwrap();
    let structure = read_mesh_structure(&indices, &mesh).unwrap();
    let expected = splineface::structure::from_ibug68(&mesh.positions()[..68]).unwrap();
    assert_eq!(structure, expected);
    // With the 68 points themselves, in their order.
    let read = read_mesh_landmarks(&indices, &mesh).unwrap();
    assert_eq!(read.structure, expected);
    assert_eq!(read.ibug.as_deref(), Some(&mesh.positions()[..68]));
    // 3D JSON: the 68 points of the ibug68 scheme, none from the structure's 40.
    let json3 = dir.join("landmarks3.json");
    let ibug: Vec<[Real; 3]> = (0..68).map(|k| [k as Real, (k * k % 5) as Real, 2.0]).collect();
    std::fs::write(
        &json3,
        serde_json::json!({ "format": "splineface/landmarks", "version": 1, "scheme": "ibug68", "points": ibug }).to_string(),
    )
    .unwrap();
    let read = read_mesh_landmarks(&json3, &mesh).unwrap();
    let points: Vec<Point3<Real>> = ibug.iter().map(|p| Point3::from(*p)).collect();
    assert_eq!(read.ibug.as_deref(), Some(&points[..]));
    assert_eq!(
        read.structure,
        splineface::structure::from_ibug68(&points).unwrap()
    );
    let forty: Vec<[Real; 3]> = read.structure.iter().map(|p| [p.x, p.y, p.z]).collect();
    std::fs::write(
        &json3,
        serde_json::json!({ "format": "splineface/landmarks", "version": 1, "scheme": "structure40", "points": forty }).to_string(),
    )
    .unwrap();
    let read = read_mesh_landmarks(&json3, &mesh).unwrap();
    assert_eq!((read.structure.len(), read.ibug), (40, None));
    // An index past the mesh's end is named with its line.
    std::fs::write(
        &indices,
        (0..68).map(|k| format!("{}\n", k + 3)).collect::<String>(),
    )
    .unwrap();
    let error = read_mesh_structure(&indices, &mesh).unwrap_err();
    assert!(
        matches!(
            error.problem,
            LandmarkProblem::IndexOutOfRange {
                line: 68,
                index: 70,
                ..
            }
        ),
        "{error}"
    );
    // 2D JSON is refused: a scan's structure is 3D.
    let json = dir.join("landmarks.json");
    let points: Vec<[Real; 2]> = (0..68).map(|k| [k as Real, 1.0]).collect();
    std::fs::write(
        &json,
        serde_json::json!({ "format": "splineface/landmarks", "version": 1, "scheme": "ibug68", "points": points }).to_string(),
    )
    .unwrap();
    let error = read_mesh_structure(&json, &mesh).unwrap_err();
    assert_eq!(error.file, json);
    assert!(
        matches!(error.problem, LandmarkProblem::Dimension { got: 2, expected: 3 }),
        "{error}"
    );
}

#[test]
fn displacement_fields_are_read_whole_or_refused_with_the_file_named() {
    let dir = scratch("library-inputs", "modes");
    let path = dir.join("modes.f32");
    // Two modes of three vertices; read through a similarity that doubles and turns them.
    let values: Vec<f32> = (0..18).map(|k| k as f32 * 0.5 - 3.0).collect();
    std::fs::write(
        &path,
        values.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>(),
    )
    .unwrap();
    let turn = Similarity3::new(Vector3::new(5.0, 6.0, 7.0), Vector3::new(0.0, 0.0, 0.3), 2.0);
    let fields = read_displacement_fields(&path, 3, &turn).unwrap();
    assert_eq!(fields.len(), 2);
    for (m, field) in fields.iter().enumerate() {
        for (v, d) in field.iter().enumerate() {
            let k = 9 * m + 3 * v;
            let raw = Vector3::new(values[k], values[k + 1], values[k + 2]).cast::<Real>();
            // A displacement turns and scales; the translation does not move it.
            assert!((d - turn * raw).norm() < 1e-12);
            assert!((d.norm() - 2.0 * raw.norm()).abs() < 1e-12);
        }
    }
    // Not a whole number of modes.
    let error = read_displacement_fields(&path, 4, &turn).unwrap_err();
    assert_eq!(error.file, path);
    assert!(
        matches!(
            error.problem,
            ModeFileProblem::Length {
                bytes: 72,
                vertices: 4
            }
        ),
        "{error}"
    );
    // A NaN is named by mode and vertex.
    let mut bad = values.clone();
    bad[9 + 4] = f32::NAN;
    std::fs::write(
        &path,
        bad.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>(),
    )
    .unwrap();
    let error = read_displacement_fields(&path, 3, &turn).unwrap_err();
    assert!(
        matches!(error.problem, ModeFileProblem::NonFinite { mode: 1, vertex: 1 }),
        "{error}"
    );
    // A missing file.
    let error = read_displacement_fields(&dir.join("missing.f32"), 3, &turn).unwrap_err();
    assert!(matches!(error.problem, ModeFileProblem::Io(_)), "{error}");
}

#[test]
fn an_output_file_is_checked_before_any_work() {
    let dir = scratch("library-inputs", "output-file");
    assert!(check_output_file(&dir.join("fine.json")).is_ok());
    assert!(matches!(
        check_output_file(&dir),
        Err(OutputError::IsADirectory { .. })
    ));
    assert!(matches!(
        check_output_file(&dir.join("missing/out.json")),
        Err(OutputError::NoSuchDirectory { .. })
    ));
    let file = dir.join("a-file");
    std::fs::write(&file, b"x").unwrap();
    let error = check_output_file(&file.join("out.json")).unwrap_err();
    assert!(
        matches!(error, OutputError::ParentNotADirectory { .. }),
        "{error}"
    );
    assert!(error.to_string().contains("is not a directory"), "{error}");
    // Nothing was left behind by the probes.
    assert_eq!(super::common::file_names(&dir), ["a-file"]);
}

#[test]
fn the_demos_settings_are_named_in_the_front_ends_units() {
    use splineface::demo::{DemoError, SceneOptions};
    let message = |options: SceneOptions| options.validate().unwrap_err().flag_message();
    let base = SceneOptions::default();
    assert!(base.validate().is_ok());
    assert_eq!(
        message(SceneOptions { photos: 0, ..base }),
        "--photos 0: between 1 and 200, please"
    );
    // The noise is a fraction; the message speaks in percent, as the flag and keyword take it.
    assert_eq!(
        message(SceneOptions { noise: -0.01, ..base }),
        "--noise -1: must be a finite percentage, 0 or more"
    );
    assert_eq!(
        message(SceneOptions {
            size: (32, 400),
            ..base
        }),
        "--size 32x400: each side must be between 64 and 4096"
    );
    assert!(matches!(
        splineface::demo::scene(&SceneOptions {
            noise: Real::NAN,
            ..base
        }),
        Err(DemoError::Setting(_))
    ));
}

#[test]
fn the_mean_face_is_the_reference_unchanged_in_the_units_asked_for() {
    let reference = ReferenceFace::embedded();
    let canonical = MeanFace::new(reference, Units::Canonical, &MeshOptions::default()).unwrap();
    let mm = MeanFace::new(
        reference,
        Units::Millimetres { eye_distance: 70.0 },
        &MeshOptions::default(),
    )
    .unwrap();
    assert_eq!(canonical.structure, reference.structure());
    assert_eq!(canonical.photo_structure, reference.photo_structure());
    let scale = 70.0 / 50.0;
    for (a, b) in canonical.mesh.positions().iter().zip(mm.mesh.positions()) {
        assert!((a * scale - b).norm() < 1e-9);
    }
    assert_eq!(canonical.mesh.triangles(), mm.mesh.triangles());
    // A spacing out of range is the mesher's error, not a panic.
    assert!(MeanFace::new(reference, Units::Canonical, &MeshOptions { spacing: -1.0 }).is_err());
}
