//! The reference face: the embedded default, the file format, building from synthetic scans
//! with known answers, and (ignored without `../shared`) the real ICT mean face.

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Point2, Point3, Similarity3, Translation3, UnitQuaternion, Vector3};
use splineface::landmarks::read_vertex_indices;
use splineface::mesh::{TriangleMesh, read_mesh, write_mesh};
use splineface::reference::{
    ReferenceError, ReferenceFace, ReferenceOptions, ReferenceScan, ReferenceSource, build_reference,
    build_reference_with_space,
};
use splineface::structure::{LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE, delaunay_edges, from_ibug68};

fn source(name: &str) -> ReferenceSource {
    ReferenceSource {
        mesh: name.into(),
        mesh_fnv1a64: "0".into(),
        landmarks: "none".into(),
        vertices: 0,
        triangles: 0,
    }
}

/// A smooth synthetic face: a broad bump in the canonical frame, zero at the eye centres so
/// that the embedded structure lifted onto it is already canonical.
fn height(x: f64, y: f64) -> f64 {
    let bump = |x: f64, y: f64| 30.0 * (-(x * x + (y + 20.0) * (y + 20.0)) / (2.0 * 60.0 * 60.0)).exp();
    bump(x, y) - bump(25.0, 0.0)
}

/// The largest distance between two references' surfaces over the first one's face region.
fn face_difference(a: &ReferenceFace, b: &ReferenceFace) -> f64 {
    let mut worst: f64 = 0.0;
    for i in 0..=60 {
        for j in 0..=60 {
            let (u, v) = (i as f64 / 60.0, j as f64 / 60.0);
            if a.in_face_region(u, v) {
                let d = a.surface().eval(u, v).unwrap() - b.surface().eval(u, v).unwrap();
                worst = worst.max(d.norm());
            }
        }
    }
    worst
}

/// The height field `height` tessellated over a square wider than any face region, with the
/// embedded reference's structure lifted onto it.
pub(crate) fn synthetic_scan() -> ReferenceScan {
    height_field_scan(height, -150.0..=150.0, -150.0..=150.0, 121)
}

/// A height field tessellated over `xs × ys` (`n` vertices a side), with the embedded
/// reference's structure lifted onto it.
pub(crate) fn height_field_scan(
    height: impl Fn(f64, f64) -> f64,
    xs: std::ops::RangeInclusive<f64>,
    ys: std::ops::RangeInclusive<f64>,
    n: usize,
) -> ReferenceScan {
    let at = |range: &std::ops::RangeInclusive<f64>, k: usize| {
        range.start() + (range.end() - range.start()) * k as f64 / (n - 1) as f64
    };
    let positions: Vec<Point3<f64>> = (0..n * n)
        .map(|k| {
            let (x, y) = (at(&xs, k % n), at(&ys, k / n));
            Point3::new(x, y, height(x, y))
        })
        .collect();
    let mut triangles = Vec::new();
    for j in 0..n as u32 - 1 {
        for i in 0..n as u32 - 1 {
            let a = j * n as u32 + i;
            triangles.push([a, a + 1, a + n as u32 + 1]);
            triangles.push([a, a + n as u32 + 1, a + n as u32]);
        }
    }
    let structure = ReferenceFace::embedded()
        .structure()
        .iter()
        .map(|p| Point3::new(p.x, p.y, height(p.x, p.y)))
        .collect();
    ReferenceScan {
        mesh: TriangleMesh::new(positions, triangles).unwrap(),
        structure,
        landmarks: None,
        source: source("synthetic"),
    }
}

#[test]
fn the_embedded_reference_is_consistent() {
    let reference = ReferenceFace::embedded();
    let t = reference.structure();
    assert_eq!(t.len(), 40);
    assert!((t[RIGHT_EYE_CENTRE] - Point3::new(-25.0, 0.0, 0.0)).norm() < 1e-9);
    assert!((t[LEFT_EYE_CENTRE] - Point3::new(25.0, 0.0, 0.0)).norm() < 1e-9);
    let frontal: Vec<Point2<f64>> = t.iter().map(|p| p.xy()).collect();
    assert_eq!(reference.edges(), delaunay_edges(&frontal).unwrap().as_slice());
    // The committed file was built with the documented defaults.
    assert_eq!(reference.fit().options, ReferenceOptions::default());
    assert_eq!(reference.surface().rows(), ReferenceOptions::default().grid);
    // The nose tip is in the face region and in front of the eyes.
    let nose = t[28];
    let uv = reference.frame().parameters(nose.x, nose.y);
    assert!(reference.in_face_region(uv.x, uv.y));
    assert!(reference.surface().eval(uv.x, uv.y).unwrap().z > 20.0);
    assert!(!reference.in_face_region(0.0, 0.0));
}

#[test]
fn reference_json_round_trip_is_exact() {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("reference/ict-mean-face.json"))
            .unwrap();
    let reference = ReferenceFace::from_json(&text).unwrap();
    assert_eq!(&reference, ReferenceFace::embedded());
    assert_eq!(reference.to_json(), text);
    assert_eq!(ReferenceFace::from_json(&reference.to_json()).unwrap(), reference);
}

#[test]
fn the_photo_structure_is_what_the_photo_stages_deform_from() {
    let reference = ReferenceFace::embedded();
    let measured = reference
        .photo_structure_measured()
        .expect("the default carries one");
    assert_eq!(reference.photo_structure(), measured.points.as_slice());
    assert!(measured.note.contains("photo_eval"));
    // It is unified like the structure (eye centres at (±25, 0, 0)) and differs from it.
    let p = reference.photo_structure();
    assert!((p[RIGHT_EYE_CENTRE] - Point3::new(-25.0, 0.0, 0.0)).norm() < 1e-9);
    assert!((p[LEFT_EYE_CENTRE] - Point3::new(25.0, 0.0, 0.0)).norm() < 1e-9);
    assert!(
        p.iter()
            .zip(reference.structure())
            .any(|(a, b)| (a - b).norm() > 1.0)
    );
    // The photo stages' reference: its structure is the photo structure, the rest unchanged.
    let seen = reference.as_seen_in_photos();
    assert_eq!(seen.structure(), reference.photo_structure());
    assert_eq!(seen.surface(), reference.surface());
    assert_eq!(seen.clip(), reference.clip());
    // Without one, the photo structure is the structure, and a version 1 file reads back.
    let plain = reference
        .clone()
        .with_photo_structure(None)
        .unwrap()
        .with_space(None)
        .unwrap();
    assert_eq!(plain.photo_structure(), plain.structure());
    assert!(matches!(plain.as_seen_in_photos(), std::borrow::Cow::Borrowed(_)));
    let mut old: serde_json::Value = serde_json::from_str(&plain.to_json()).unwrap();
    old["version"] = 1.into();
    assert_eq!(ReferenceFace::from_json(&old.to_string()).unwrap(), plain);
    // A bad photo structure is refused.
    let short = splineface::reference::PhotoStructure {
        points: p[..39].to_vec(),
        note: String::new(),
    };
    let err = reference.clone().with_photo_structure(Some(short)).unwrap_err();
    assert!(
        matches!(&err, splineface::reference::ReferenceError::PhotoStructure { problem } if problem.contains("39 points")),
        "{err}"
    );
}

#[test]
fn the_embedded_reference_carries_a_face_space() {
    let reference = ReferenceFace::embedded();
    let modes = reference.space_modes().expect("the default carries one");
    assert_eq!(modes.sigma.len(), 60);
    assert!(modes.note.contains("ICT-FaceKit") && modes.note.contains("MIT"));
    let space = reference.face_space().unwrap();
    assert_eq!(space.mode_count(), 60);
    // All weights zero: the reference itself.
    let zero = vec![0.0; 60];
    assert_eq!(space.surfaces().surface(&zero).unwrap(), *reference.surface());
    assert_eq!(space.structure(&zero).unwrap(), reference.structure());
    // The modes are real shape changes: a unit weight moves the surface by millimetres.
    let mut one = zero.clone();
    one[0] = 1.0;
    let moved = space.surfaces().surface(&one).unwrap();
    let d = (moved.eval(0.5, 0.5).unwrap() - reference.surface().eval(0.5, 0.5).unwrap()).norm();
    assert!(d > 0.05 && d < 20.0, "{d}");
    // On the photo stages' reference the space's base structure is the photo structure.
    let seen = reference.as_seen_in_photos().face_space().unwrap();
    assert_eq!(seen.structure(&zero).unwrap(), reference.photo_structure());
    // Version 2 files cannot carry one; a grid of the wrong size or encoding is refused.
    let mut json: serde_json::Value = serde_json::from_str(&reference.to_json()).unwrap();
    let mut old = json.clone();
    old["version"] = 2.into();
    let err = ReferenceFace::from_json(&old.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("version 3"), "{err}");
    let mut short = json.clone();
    short["space"]["modes"] = 59.into();
    let err = ReferenceFace::from_json(&short.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("bytes"), "{err}");
    json["space"]["grid_encoding"] = "f64".into();
    let err = ReferenceFace::from_json(&json.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("encoding"), "{err}");
    // Modes that do not match the grid are refused when set.
    let mut bad = modes.clone();
    bad.grid[3].pop();
    let err = reference.clone().with_space(Some(bad)).unwrap_err();
    assert!(
        matches!(&err, splineface::reference::ReferenceError::Space { problem } if problem.contains("mode 3")),
        "{err}"
    );
}

#[test]
fn the_embedded_space_carries_ictfacekits_expressions() {
    let reference = ReferenceFace::embedded();
    let modes = reference.space_modes().unwrap();
    let expressions = &modes.expressions;
    assert_eq!(expressions.len(), 53);
    for name in [
        "jawOpen",
        "mouthSmile_L",
        "mouthSmile_R",
        "browInnerUp_L",
        "mouthPucker",
    ] {
        assert!(expressions.names.iter().any(|n| n == name), "{name}");
    }
    assert!(expressions.note.contains("ICT-FaceKit") && expressions.note.contains("MIT"));
    // jawOpen lowers the chin (the contour's middle point, 4) by centimetres and leaves the
    // right eye's outer corner (15) nearly where it was.
    let space = reference.face_space().unwrap();
    let jaw = expressions.names.iter().position(|n| n == "jawOpen").unwrap();
    let mut e = vec![0.0; 53];
    e[jaw] = 1.0;
    let zero = vec![0.0; 60];
    let neutral = space.structure(&zero).unwrap();
    let open = space.structure_with_expression(&zero, &e).unwrap();
    assert!(
        open[4].y < neutral[4].y - 10.0,
        "{} vs {}",
        open[4].y,
        neutral[4].y
    );
    assert!((open[15] - neutral[15]).norm() < 1.0);
    // Weights outside [0, 1] or of the wrong count are refused.
    e[jaw] = 1.5;
    assert!(space.structure_with_expression(&zero, &e).is_err());
    assert!(space.structure_with_expression(&zero, &[0.5]).is_err());
    // The surface follows: the chin's surface point moves down with the structure.
    let face = space.face_with_expression(reference, &zero, &{
        let mut e = vec![0.0; 53];
        e[jaw] = 1.0;
        e
    });
    assert!(face.is_ok());
    // Version 3 files cannot carry expressions; names must be one per mode, distinct.
    let json: serde_json::Value = serde_json::from_str(&reference.to_json()).unwrap();
    let mut old = json.clone();
    old["version"] = 3.into();
    let err = ReferenceFace::from_json(&old.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("version 4"), "{err}");
    let mut short = json.clone();
    short["space"]["expressions"]["names"]
        .as_array_mut()
        .unwrap()
        .pop();
    let err = ReferenceFace::from_json(&short.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("space expressions"), "{err}");
    let mut twice = json;
    twice["space"]["expressions"]["names"][1] = "browDown_L".into();
    let err = ReferenceFace::from_json(&twice.to_string())
        .unwrap_err()
        .to_string();
    assert!(err.contains("repeated"), "{err}");
    // Without expressions, a space writes and reads as version 3 did.
    let plain = reference
        .clone()
        .with_space(Some(modes.clone().without_expressions()))
        .unwrap();
    let back = ReferenceFace::from_json(&plain.to_json()).unwrap();
    assert!(back.space_modes().unwrap().expressions.is_empty());
}

#[test]
fn a_refined_reference_describes_the_same_faces_on_a_finer_grid() {
    use splineface::bspline::Direction;
    let reference = ReferenceFace::embedded();
    let finer = reference
        .refine_knots(Direction::U, &[0.45, 0.5, 0.55])
        .and_then(|r| r.refine_knots(Direction::V, &[0.3]))
        .unwrap();
    assert_eq!((finer.surface().rows(), finer.surface().cols()), (35, 33));
    let (space, fine_space) = (reference.face_space().unwrap(), finer.face_space().unwrap());
    // A member with an expression: the identity and expression grids are both refined. The
    // modes are stored at f32, so the refined ones are within its rounding (canonical units,
    // the face about 200 across).
    let mut rng = crate::common::Lcg(3);
    let w: Vec<f64> = (0..space.mode_count()).map(|_| rng.gaussian()).collect();
    let mut e = vec![0.0; space.expressions().len()];
    e[0] = 0.8;
    e[20] = 0.5;
    let a = space.face_with_expression(reference, &w, &e).unwrap();
    let b = fine_space.face_with_expression(&finer, &w, &e).unwrap();
    let mut largest: f64 = 0.0;
    for i in 0..=20 {
        for j in 0..=20 {
            let (u, v) = (i as f64 / 20.0, j as f64 / 20.0);
            let (p, q) = (a.surface().eval(u, v).unwrap(), b.surface().eval(u, v).unwrap());
            largest = largest.max((p - q).norm());
        }
    }
    assert!(largest < 1e-5, "{largest}");
    assert_eq!(space.structure(&w).unwrap(), fine_space.structure(&w).unwrap());
    // It writes and reads back as it is.
    let back = ReferenceFace::from_json(&finer.to_json()).unwrap();
    assert_eq!(&back, &finer);
    // A knot a fourth time, or outside the domain, is refused.
    assert!(finer.refine_knots(Direction::U, &[0.5, 0.5, 0.5]).is_err());
    assert!(reference.refine_knots(Direction::V, &[1.5]).is_err());
}

#[test]
fn malformed_references_are_refused() {
    let text = ReferenceFace::embedded().to_json();
    let mut value: serde_json::Value = serde_json::from_str(&text).unwrap();
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(Edit, &str)> = vec![
        (Box::new(|v| v["format"] = "other".into()), "format is \"other\""),
        (Box::new(|v| v["version"] = 9.into()), "version 9"),
        (
            Box::new(|v| {
                v["structure"].as_array_mut().unwrap().pop();
            }),
            "structure has 39 points",
        ),
        (
            Box::new(|v| v["edges"][0] = serde_json::json!([3, 3])),
            "edge [3, 3]",
        ),
        (Box::new(|v| v["edges"][1] = v["edges"][0].clone()), "is repeated"),
        (
            Box::new(|v| v["clip"][2] = serde_json::json!([0.5, 1.5])),
            "clip point 2 lies outside",
        ),
        (
            Box::new(|v| {
                let first = v["clip"][0].clone();
                for p in v["clip"].as_array_mut().unwrap() {
                    *p = first.clone();
                }
            }),
            "clip polygon has 1 distinct points",
        ),
        (
            // Knots 8 to 11 (degree 3) made equal: the surface tears along that line.
            Box::new(|v| {
                let knot = v["surface"]["knots_u"]["knots"][8].clone();
                for k in 9..12 {
                    v["surface"]["knots_u"]["knots"][k] = knot.clone();
                }
            }),
            "the surface is discontinuous at u",
        ),
        (
            Box::new(|v| v["frame"]["x"] = serde_json::json!([1.0, -1.0])),
            "frame is not a finite box",
        ),
        (Box::new(|v| v["extra"] = 1.into()), "unknown field `extra`"),
        (
            Box::new(|v| {
                v["photo_structure"]["points"].as_array_mut().unwrap().pop();
            }),
            "photo_structure has 39 points",
        ),
        (
            Box::new(|v| v["photo_structure"]["points"][3] = serde_json::json!([1.0, "x", 2.0])),
            "invalid type",
        ),
        (
            Box::new(|v| v["version"] = 1.into()),
            "photo_structure needs format version 2",
        ),
    ];
    for (edit, expected) in cases {
        let original = value.clone();
        edit(&mut value);
        let message = ReferenceFace::from_json(&value.to_string())
            .unwrap_err()
            .to_string();
        assert!(
            message.contains(expected),
            "got {message:?}, expected {expected:?}"
        );
        value = original;
    }
}

#[test]
fn a_smooth_scan_is_fitted_closely() {
    let scan = synthetic_scan();
    let reference =
        build_reference(std::slice::from_ref(&scan), &ReferenceOptions::default(), "test").unwrap();
    let fit = reference.fit();
    // The scan is piecewise linear (2.5-unit triangles) over a smooth bump: the fit is limited by
    // the scan's own flat facets, whose deviation from the bump is below 0.02 units.
    assert!(fit.rms < 0.01 && fit.max < 0.05, "{fit:?}");
    // The surface follows the closed form across the face region, also between samples.
    let frame = reference.frame();
    for (x, y) in [(0.0, 0.0), (-40.0, -60.0), (37.3, 20.1), (-55.0, 10.0)] {
        let uv = frame.parameters(x, y);
        assert!(reference.in_face_region(uv.x, uv.y));
        let p = reference.surface().eval(uv.x, uv.y).unwrap();
        assert!(
            (p - Point3::new(x, y, height(x, y))).norm() < 0.02,
            "at ({x}, {y}): {p}"
        );
    }
}

#[test]
fn a_moved_scan_gives_the_same_reference() {
    let scan = synthetic_scan();
    let options = ReferenceOptions {
        grid: 12,
        sample_spacing: 1.0,
        ..ReferenceOptions::default()
    };
    let base = build_reference(std::slice::from_ref(&scan), &options, "").unwrap();
    // Scaled to centimetres, turned a little, moved: unification must undo all of it.
    let motion = Similarity3::from_parts(
        Translation3::new(3.0, -7.0, 40.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.2),
        0.13,
    );
    let moved = ReferenceScan {
        mesh: scan.mesh.transformed(&nalgebra::convert(motion)),
        structure: scan.structure.iter().map(|p| motion * p).collect(),
        landmarks: None,
        source: source("moved"),
    };
    let other = build_reference(std::slice::from_ref(&moved), &options, "").unwrap();
    let (f, g) = (other.frame(), base.frame());
    for (a, b) in f.x.iter().chain(&f.y).zip(g.x.iter().chain(&g.y)) {
        assert!((a - b).abs() < 1e-9, "{f:?} vs {g:?}");
    }
    assert!(
        face_difference(&base, &other) < 1e-6,
        "{}",
        face_difference(&base, &other)
    );
    // Two copies average to the same.
    let twice = build_reference(&[scan.clone(), moved], &options, "").unwrap();
    assert_eq!(twice.provenance().sources.len(), 2);
    assert!(
        face_difference(&base, &twice) < 1e-6,
        "{}",
        face_difference(&base, &twice)
    );
}

#[test]
fn bad_inputs_are_refused() {
    let scan = synthetic_scan();
    let build = |options: ReferenceOptions| build_reference(std::slice::from_ref(&scan), &options, "");
    assert!(matches!(
        build_reference(&[], &ReferenceOptions::default(), ""),
        Err(ReferenceError::NoScans)
    ));
    for options in [
        ReferenceOptions {
            grid: 3,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            smoothness: -1.0,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            smoothness: f64::NAN,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            sample_spacing: 0.0,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            sample_spacing: 1e-4,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            margin: 0.9,
            ..ReferenceOptions::default()
        },
        ReferenceOptions {
            fit_margin: 2.0,
            ..ReferenceOptions::default()
        },
    ] {
        assert!(
            matches!(build(options), Err(ReferenceError::Option { .. })),
            "{options:?}"
        );
    }
    // Landmarks that do not belong to the scan: the face region misses it.
    let mut far = scan.clone();
    far.structure = far
        .structure
        .iter()
        .map(|p| p + Vector3::new(0.0, 500.0, 0.0))
        .collect();
    assert!(matches!(
        build_reference(&[far], &ReferenceOptions::default(), ""),
        Err(ReferenceError::TooFewSamples { .. })
    ));
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("splineface-reference-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// Writes the synthetic scan as OBJ and its structure as a `structure40` JSON landmark file.
fn synthetic_files() -> (PathBuf, PathBuf) {
    let scan = synthetic_scan();
    let mesh = scratch("scan.obj");
    write_mesh(&mesh, &scan.mesh).unwrap();
    let landmarks = scratch("scan.json");
    let points: Vec<Vec<f64>> = scan.structure.iter().map(|p| vec![p.x, p.y, p.z]).collect();
    let json = serde_json::json!({
        "format": "splineface/landmarks", "version": 1, "scheme": "structure40", "points": points
    });
    std::fs::write(&landmarks, json.to_string()).unwrap();
    (mesh, landmarks)
}

fn splineface(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_splineface"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn the_command_builds_a_reference_and_refuses_bad_input() {
    let (mesh, landmarks) = synthetic_files();
    let (mesh, landmarks) = (mesh.to_str().unwrap(), landmarks.to_str().unwrap());
    let out = scratch("out.json");
    let out_str = out.to_str().unwrap();
    let run = splineface(&[
        "fit-reference",
        "--mesh",
        mesh,
        "--landmarks",
        landmarks,
        "--out",
        out_str,
        "--grid",
        "10",
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let reference = ReferenceFace::from_json(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(reference.surface().rows(), 10);
    assert_eq!(reference.provenance().sources[0].mesh, "scan.obj");
    std::fs::remove_file(&out).unwrap();

    let refused = [
        (
            vec!["--mesh", mesh, "--mesh", mesh, "--landmarks", landmarks],
            "2 --mesh but 1 --landmarks",
        ),
        (
            vec!["--mesh", "/no/such.obj", "--landmarks", landmarks],
            "/no/such.obj",
        ),
        (
            vec!["--mesh", mesh, "--landmarks", mesh],
            "scan.obj: line 2: `v -150.0",
        ),
        (
            vec!["--mesh", mesh, "--landmarks", landmarks, "--grid", "2"],
            "option grid = 2",
        ),
        (
            vec!["--mesh", mesh, "--landmarks", landmarks, "--smoothness", "nan"],
            "smoothness",
        ),
        (
            vec!["--mesh", mesh, "--landmarks", landmarks, "--space-from-scans"],
            "at least 3 for a face space learnt from scans",
        ),
    ];
    for (args, expected) in refused {
        let mut full = vec!["fit-reference", "--out", out_str];
        full.extend(args);
        let run = splineface(&full);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{full:?} succeeded");
        assert!(stderr.contains(expected), "{full:?}: {stderr}");
        assert!(!out.exists(), "{full:?} left an output file");
    }
}

/// 68 vertex indices of the synthetic scan laid out like iBUG points: each structure point's
/// sources sit at its position, the iBUG points no structure point uses halfway between their
/// neighbours (the inner lips at the outer lips' places), all snapped to the nearest vertex.
fn synthetic_ibug_vertices(scan: &ReferenceScan) -> Vec<usize> {
    use splineface::structure::POINTS;
    let mut at: Vec<Option<Point2<f64>>> = vec![None; 68];
    for (definition, p) in POINTS.iter().zip(&scan.structure) {
        if let [single] = definition.ibug_sources {
            at[*single] = Some(p.xy());
        } else if definition.ibug_sources.len() == 2 {
            for &i in definition.ibug_sources {
                at[i] = Some(p.xy());
            }
        }
    }
    for (i, before, after) in [1, 3, 5, 7, 9, 11, 13, 15, 18, 20, 23, 25, 32, 34, 49, 53, 55]
        .map(|i| (i, i - 1, i + 1))
        .into_iter()
        .chain([(59, 58, 48)])
    {
        at[i] = Some(Point2::from(
            (at[before].unwrap().coords + at[after].unwrap().coords) / 2.0,
        ));
    }
    for (inner, outer) in (60..68).zip([48, 50, 51, 52, 54, 56, 57, 58]) {
        at[inner] = at[outer];
    }
    let positions = scan.mesh.positions();
    at.iter()
        .map(|p| {
            let p = p.expect("every iBUG point placed");
            (0..positions.len())
                .min_by(|&a, &b| {
                    (positions[a].xy() - p)
                        .norm()
                        .total_cmp(&(positions[b].xy() - p).norm())
                })
                .unwrap()
        })
        .collect()
}

#[test]
fn the_command_learns_a_space_and_its_landmarks_from_scans() {
    let mut args: Vec<String> = vec![
        "fit-reference".into(),
        "--space-from-scans".into(),
        "--grid".into(),
        "12".into(),
    ];
    let mut expected = vec![Vector3::zeros(); 68];
    let shapes = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)];
    for (k, &(a, b)) in shapes.iter().enumerate() {
        let scan = varied_scan(a, b);
        let mesh = scratch(&format!("learnt-{k}.obj"));
        write_mesh(&mesh, &scan.mesh).unwrap();
        let indices = synthetic_ibug_vertices(&scan);
        let landmarks = scratch(&format!("learnt-{k}.txt"));
        let list: Vec<String> = indices.iter().map(ToString::to_string).collect();
        std::fs::write(&landmarks, list.join("\n")).unwrap();
        // What the space's base must be: the mean of the landmark vertices, each scan in the
        // canonical frame its own structure (made from those vertices) gives it.
        let ibug: Vec<Point3<f64>> = indices.iter().map(|&i| scan.mesh.positions()[i]).collect();
        let (to_canonical, _) = splineface::structure::unify(&from_ibug68(&ibug).unwrap()).unwrap();
        for (e, p) in expected.iter_mut().zip(&ibug) {
            *e += (to_canonical * p).coords / shapes.len() as f64;
        }
        for (flag, path) in [("--mesh", mesh), ("--landmarks", landmarks)] {
            args.push(flag.into());
            args.push(path.to_str().unwrap().into());
        }
    }
    let out = scratch("learnt-space.json");
    let _ = std::fs::remove_file(&out);
    args.extend(["--out".into(), out.to_str().unwrap().into()]);
    let run = splineface(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(
        String::from_utf8_lossy(&run.stdout).contains("moving the 68 landmarks"),
        "{}",
        String::from_utf8_lossy(&run.stdout)
    );
    let reference = ReferenceFace::from_json(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let modes = reference.space_modes().unwrap();
    assert_eq!(modes.landmark_base.len(), 68);
    assert_eq!(modes.landmarks.len(), modes.sigma.len());
    for (j, (p, e)) in modes.landmark_base.iter().zip(&expected).enumerate() {
        assert!((p.coords - e).norm() < 1e-6, "landmark {j}: {p} against {e}");
    }
}

/// A displacement field as a function of a vertex's position.
type Field = fn(&Point3<f64>) -> Vector3<f64>;

/// Little-endian float32 displacement fields `[mode][vertex][3]` of `mesh`.
fn write_fields(path: &Path, mesh: &TriangleMesh, fields: &[Field]) {
    let mut bytes = Vec::new();
    for f in fields {
        for p in mesh.positions() {
            for c in f(p).iter() {
                bytes.extend_from_slice(&(*c as f32).to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn the_command_builds_a_face_space_from_displacement_fields() {
    let scan = synthetic_scan();
    let mesh_path = scratch("space-scan.obj");
    write_mesh(&mesh_path, &scan.mesh).unwrap();
    let indices = scratch("space-scan.txt");
    let list: Vec<String> = synthetic_ibug_vertices(&scan)
        .iter()
        .map(ToString::to_string)
        .collect();
    std::fs::write(&indices, list.join("\n")).unwrap();
    let identity = scratch("identity.f32");
    write_fields(
        &identity,
        &scan.mesh,
        &[
            |p| Vector3::new(0.0, 0.0, 0.1 * p.x),
            |p| Vector3::new(0.001 * p.y * p.y, 0.0, 0.0),
        ],
    );
    let expressions = scratch("expressions.f32");
    write_fields(
        &expressions,
        &scan.mesh,
        &[|p| Vector3::new(0.0, 0.002 * p.x * p.x, 0.0)],
    );
    let names = scratch("names.txt");
    std::fs::write(&names, "# one name a line\nsmile\n").unwrap();
    let out = scratch("space-out.json");
    let path = |p: &PathBuf| p.to_str().unwrap().to_owned();
    let base = vec![
        "fit-reference".to_owned(),
        "--mesh".to_owned(),
        path(&mesh_path),
        "--landmarks".to_owned(),
        path(&indices),
        "--out".to_owned(),
        path(&out),
        "--grid".to_owned(),
        "12".to_owned(),
    ];
    let with = |extra: &[&str]| {
        let mut all = base.clone();
        all.extend(extra.iter().map(|s| (*s).to_owned()));
        all
    };
    let run = |args: Vec<String>| {
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        splineface(&refs)
    };
    let good = with(&[
        "--identity-modes",
        &path(&identity),
        "--expression-modes",
        &path(&expressions),
        "--expression-names",
        &path(&names),
        "--modes-note",
        "synthetic fields",
    ]);
    let result = run(good);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let reference = ReferenceFace::from_json(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let modes = reference.space_modes().expect("a face space");
    assert_eq!(modes.sigma, [1.0, 1.0]);
    assert_eq!(modes.expressions.names, ["smile"]);
    assert_eq!(modes.note, "synthetic fields");
    // The first mode (z = 0.1 x in the scan's frame) tilts the face: the structure's right
    // eye centre (x = −25) moves back, the left one forward, by about 0.1 × 25 units (the
    // canonical frame's scale is the scan's up to the eye distance).
    let z = |p: usize| modes.structure[0][p].z;
    assert!(
        z(RIGHT_EYE_CENTRE) < -1.5 && z(LEFT_EYE_CENTRE) > 1.5,
        "{} {}",
        z(RIGHT_EYE_CENTRE),
        z(LEFT_EYE_CENTRE)
    );
    std::fs::remove_file(&out).unwrap();

    let truncated = scratch("truncated.f32");
    std::fs::write(&truncated, &std::fs::read(&identity).unwrap()[..100]).unwrap();
    let (_, json_landmarks) = synthetic_files();
    let refused: Vec<(Vec<String>, String)> = vec![
        (
            with(&["--identity-modes", &path(&truncated)]),
            format!("{}: 100 bytes is not a whole number of modes", path(&truncated)),
        ),
        (
            with(&[
                "--identity-modes",
                &path(&identity),
                "--expression-modes",
                &path(&identity),
                "--expression-names",
                &path(&names),
            ]),
            format!("{}: 1 names for the 2 expression modes", path(&names)),
        ),
        (
            {
                let mut args = with(&["--identity-modes", &path(&identity)]);
                args[4] = path(&json_landmarks);
                args
            },
            "need the landmarks as 68 vertex indices".to_owned(),
        ),
        (
            with(&[
                "--expression-modes",
                &path(&expressions),
                "--expression-names",
                &path(&names),
            ]),
            "--identity-modes".to_owned(),
        ),
    ];
    for (args, expected) in refused {
        let result = run(args.clone());
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert!(!result.status.success(), "{args:?} succeeded");
        assert!(stderr.contains(&expected), "{args:?}: {stderr}");
        assert!(!out.exists(), "{args:?} left an output file");
    }
}

/// The synthetic scan with its heights changed by `a` times a cheek-width field and `b` times a
/// chin-depth field (its structure lifted onto the new heights).
fn varied_scan(a: f64, b: f64) -> ReferenceScan {
    let change = |p: &Point3<f64>| a * 4.0 * (p.x / 40.0).powi(2) + b * 3.0 * ((p.y + 40.0) / 40.0).powi(2);
    let base = synthetic_scan();
    let positions = base
        .mesh
        .positions()
        .iter()
        .map(|p| Point3::new(p.x, p.y, p.z + change(p)))
        .collect();
    ReferenceScan {
        mesh: TriangleMesh::new(positions, base.mesh.triangles().to_vec()).unwrap(),
        structure: base
            .structure
            .iter()
            .map(|p| Point3::new(p.x, p.y, p.z + change(p)))
            .collect(),
        landmarks: None,
        source: source("varied"),
    }
}

/// The options the learnt spaces' tests build with: a 12 × 12 grid.
fn grid_12() -> ReferenceOptions {
    ReferenceOptions {
        grid: 12,
        ..ReferenceOptions::default()
    }
}

#[test]
fn a_face_space_learnt_from_scans_holds_each_scan() {
    use splineface::face::DenseFitOptions;
    use splineface::mesh::ClosestPoints;
    let scans: Vec<ReferenceScan> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, -1.0)]
        .iter()
        .map(|&(a, b)| varied_scan(a, b))
        .collect();
    let options = grid_12();
    let reference = build_reference_with_space(&scans, &options, "test").unwrap();
    let modes = reference.space_modes().unwrap();
    assert!(
        (1..=3).contains(&modes.sigma.len()),
        "{} modes",
        modes.sigma.len()
    );
    assert!(modes.note.contains("principal components of the 4 scans"));
    // Without the space it is the reference build_reference makes.
    let plain = build_reference(&scans, &options, "test").unwrap();
    assert_eq!(plain.surface(), reference.surface());
    // Each scan is a member: fitted densely from its own structure, the member lies on the scan
    // (in its canonical frame) to within the grid's own fitting error.
    let space = reference.face_space().unwrap();
    for scan in &scans {
        let (to_canonical, canonical) = splineface::structure::unify(&scan.structure).unwrap();
        let mesh = scan.mesh.transformed(&nalgebra::convert(to_canonical));
        let start = space.fit_structure(&canonical, &[1.0; 40], 1e-3).unwrap();
        let fit = space
            .fit_surface(
                &reference,
                &mesh,
                &start,
                &DenseFitOptions {
                    noise: 1e-3,
                    ..DenseFitOptions::default()
                },
            )
            .unwrap();
        let member = space.surfaces().surface(&fit.weights).unwrap();
        let closest = ClosestPoints::new(&mesh);
        let mut worst: f64 = 0.0;
        for i in 2..=18 {
            for j in 2..=18 {
                let (u, v) = (i as f64 / 20.0, j as f64 / 20.0);
                if reference.in_face_region(u, v) {
                    let p = fit.placement * member.eval(u, v).unwrap();
                    worst = worst.max(closest.closest(&p).distance);
                }
            }
        }
        assert!(worst < 0.5, "a scan lies {worst} units from its member");
    }
    // The mean face alone is not a member of the varied scans' space: the first varied scan is
    // far from it.
    let (to_canonical, _) = splineface::structure::unify(&scans[1].structure).unwrap();
    let mesh = scans[1].mesh.transformed(&nalgebra::convert(to_canonical));
    let closest = ClosestPoints::new(&mesh);
    let far = (2..=18)
        .flat_map(|i| (2..=18).map(move |j| (i as f64 / 20.0, j as f64 / 20.0)))
        .filter(|&(u, v)| reference.in_face_region(u, v))
        .map(|(u, v)| closest.closest(&reference.surface().eval(u, v).unwrap()).distance)
        .fold(0.0, f64::max);
    assert!(far > 1.0, "{far}");
    // Two scans are not enough.
    assert!(matches!(
        build_reference_with_space(&scans[..2], &options, ""),
        Err(ReferenceError::Option { name: "scans", .. })
    ));
}

/// [`varied_scan`] with 68 iBUG landmarks: the embedded space's, lifted onto the scan's
/// heights, its structure made from them.
fn varied_scan_with_landmarks(a: f64, b: f64) -> ReferenceScan {
    let scan = varied_scan(a, b);
    let change = |p: &Point3<f64>| a * 4.0 * (p.x / 40.0).powi(2) + b * 3.0 * ((p.y + 40.0) / 40.0).powi(2);
    let ibug: Vec<Point3<f64>> = ReferenceFace::embedded()
        .space_modes()
        .expect("the embedded reference has a face space")
        .landmark_base
        .iter()
        .map(|p| {
            let on = Point3::new(p.x, p.y, height(p.x, p.y));
            Point3::new(on.x, on.y, on.z + change(&on))
        })
        .collect();
    ReferenceScan {
        structure: from_ibug68(&ibug).unwrap(),
        landmarks: Some(ibug),
        ..scan
    }
}

#[test]
fn a_face_space_learnt_from_scans_moves_their_68_landmarks() {
    let shapes = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, -1.0)];
    let scans: Vec<ReferenceScan> = shapes
        .iter()
        .map(|&(a, b)| varied_scan_with_landmarks(a, b))
        .collect();
    let options = grid_12();
    let reference = build_reference_with_space(&scans, &options, "test").unwrap();
    // Each scan's landmarks in its canonical frame (the frame its structure gives it).
    let canonical: Vec<Vec<Point3<f64>>> = scans
        .iter()
        .map(|scan| {
            let (to_canonical, _) = splineface::structure::unify(&scan.structure).unwrap();
            scan.landmarks
                .as_ref()
                .unwrap()
                .iter()
                .map(|p| to_canonical * p)
                .collect()
        })
        .collect();
    let modes = reference.space_modes().unwrap();
    assert_eq!(modes.landmarks.len(), modes.sigma.len());
    // The base is the scans' mean.
    for (j, p) in modes.landmark_base.iter().enumerate() {
        let mean = canonical.iter().map(|l| l[j].coords).sum::<Vector3<f64>>() / scans.len() as f64;
        assert!(
            (p.coords - mean).norm() < 1e-9,
            "landmark {j}: {p} against the mean {mean}"
        );
    }
    // The weights that give a scan's structure give its landmarks (the modes are one set of
    // coefficients over the scans), in memory and through the file (`f32`).
    let reread = ReferenceFace::from_json(&reference.to_json()).unwrap();
    for (which, tolerance) in [(&reference, 1e-6), (&reread, 1e-3)] {
        let space = which.face_space().unwrap();
        assert!(space.carries_landmarks());
        for (scan, landmarks) in scans.iter().zip(&canonical) {
            let (_, structure) = splineface::structure::unify(&scan.structure).unwrap();
            let fit = space.fit_structure(&structure, &[1.0; 40], 1e-4).unwrap();
            let member = space.landmarks(&fit.weights, &[]).unwrap().unwrap();
            let worst = member
                .iter()
                .zip(landmarks)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, f64::max);
            assert!(
                worst < tolerance,
                "a scan's landmarks lie {worst} units from its member's"
            );
        }
    }
    // Only when every scan has them.
    let mut mixed = scans.clone();
    mixed[2].landmarks = None;
    let without = build_reference_with_space(&mixed, &options, "test").unwrap();
    assert!(without.space_modes().unwrap().landmark_base.is_empty());
    assert!(!without.face_space().unwrap().carries_landmarks());
    // A scan's landmarks must be 68 finite points.
    let mut short = scans.clone();
    short[1].landmarks.as_mut().unwrap().pop();
    let mut broken = scans;
    broken[3].landmarks.as_mut().unwrap()[5].z = f64::NAN;
    for (bad, scan, what) in [
        (short, 1, "expected 68 points, got 67"),
        (broken, 3, "point 5 is not finite"),
    ] {
        let error = build_reference_with_space(&bad, &options, "test").unwrap_err();
        assert!(
            matches!(error, ReferenceError::Structure { scan: k, .. } if k == scan),
            "{error:?}"
        );
        assert!(error.to_string().contains(what), "{error}");
    }
}

#[test]
#[ignore = "needs ../shared/data/ict-face (not part of the repository)"]
fn the_ict_mean_face_is_fitted_within_the_accepted_residual() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-face");
    let mesh = read_mesh(&dir.join("neutral_face.obj")).unwrap();
    let indices = read_vertex_indices(&dir.join("landmarks68.txt"), 68, mesh.positions().len()).unwrap();
    let ibug: Vec<Point3<f64>> = indices.iter().map(|&i| mesh.positions()[i]).collect();
    let scan = ReferenceScan {
        structure: from_ibug68(&ibug).unwrap(),
        mesh,
        landmarks: None,
        source: source("neutral_face.obj"),
    };
    let reference = build_reference(&[scan], &ReferenceOptions::default(), "").unwrap();
    let fit = reference.fit();
    // Accepted (reference/README.md): half the samples within 0.03 units (0.04 mm), 95% within
    // 0.45 units (0.57 mm); the rest are the nostrils, which no frontal surface holds.
    assert!(fit.median < 0.03 && fit.p95 < 0.45 && fit.rms < 0.40, "{fit:?}");
    // The committed default is this fit.
    let committed = ReferenceFace::embedded();
    assert_eq!(committed.fit().samples, fit.samples);
    for (a, b) in committed
        .surface()
        .control_points()
        .iter()
        .zip(reference.surface().control_points())
    {
        assert!((a - b).norm() < 1e-9, "{a} vs {b}");
    }
}
