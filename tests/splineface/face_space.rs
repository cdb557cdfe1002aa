//! The statistical face space on a reference: modes carried from per-vertex fields, members,
//! the MAP fit to 3D landmarks and the dense fit to a mesh, on a synthetic scan with known
//! answers.

use std::sync::OnceLock;

use nalgebra::{Point3, Similarity3, Translation3, UnitQuaternion, Vector3};
use splineface::face::{DenseFitOptions, ExpressionPrior, FaceError, FaceSpace, PhotoFitOptions};
use splineface::mesh::TriangleMesh;
use splineface::reference::{ReferenceFace, ReferenceOptions, build_reference};
use splineface::structure::POINT_COUNT;

use crate::reference::synthetic_scan;

/// The synthetic scan (already in the canonical frame) and the reference fitted to it.
fn fixture() -> &'static (TriangleMesh, ReferenceFace) {
    static FIXTURE: OnceLock<(TriangleMesh, ReferenceFace)> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let scan = synthetic_scan();
        let reference =
            build_reference(std::slice::from_ref(&scan), &ReferenceOptions::default(), "test").unwrap();
        (scan.mesh, reference)
    })
}

/// 68 distinct vertices spread over the middle of the scan (stand-ins for landmark vertices).
fn landmarks(mesh: &TriangleMesh) -> Vec<usize> {
    let near = |x: f64, y: f64| {
        (0..mesh.positions().len())
            .min_by(|&a, &b| {
                let d = |k: usize| (mesh.positions()[k].x - x).powi(2) + (mesh.positions()[k].y - y).powi(2);
                d(a).total_cmp(&d(b))
            })
            .unwrap()
    };
    (0..68)
        .map(|k| near(-40.0 + 10.0 * (k % 9) as f64, -50.0 + 12.0 * (k / 9) as f64))
        .collect()
}

/// Per-vertex fields: `z` linear in `x` (exactly representable), `x` quadratic in `y` and `z`
/// quadratic in `x` (not similarities, so the landmark fit can tell them apart from the pose).
fn fields(mesh: &TriangleMesh) -> Vec<Vec<Vector3<f64>>> {
    type Field = fn(&Point3<f64>) -> Vector3<f64>;
    let f: [Field; 3] = [
        |p| Vector3::new(0.0, 0.0, 0.1 * p.x),
        |p| Vector3::new(0.001 * p.y * p.y, 0.0, 0.0),
        |p| Vector3::new(0.0, 0.0, 0.002 * p.x * p.x),
    ];
    f.iter()
        .map(|f| mesh.positions().iter().map(f).collect())
        .collect()
}

/// Photo-fit options with noise `noise` and no expressions.
fn neutral(noise: f64) -> PhotoFitOptions {
    PhotoFitOptions {
        noise,
        expressions: None,
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    }
}

fn space() -> FaceSpace {
    let (mesh, reference) = fixture();
    FaceSpace::from_displacements(reference, mesh, &landmarks(mesh), &fields(mesh), &[1.0, 1.0, 1.0]).unwrap()
}

#[test]
fn a_field_the_knots_represent_is_carried_exactly() {
    let (mesh, reference) = fixture();
    let space = space();
    let member = space.surfaces().surface(&[0.7, 0.0, 0.0]).unwrap();
    let frame = reference.frame();
    for i in 0..=10 {
        for j in 0..=10 {
            let (u, v) = (i as f64 / 10.0, j as f64 / 10.0);
            let base = reference.surface().eval(u, v).unwrap();
            let x = frame.position(u, v).x;
            let expected = base + Vector3::new(0.0, 0.0, 0.7 * 0.1 * x);
            let got = member.eval(u, v).unwrap();
            assert!((got - expected).norm() < 1e-8, "({u}, {v}): {got} vs {expected}");
        }
    }
    // The structure moves by the landmark vertices' displacements, reduced like the points.
    let lm = landmarks(mesh);
    let moved = space.structure(&[1.0, 0.0, 0.0]).unwrap();
    let ibug: Vec<Point3<f64>> = lm.iter().map(|&v| Point3::from(fields(mesh)[0][v])).collect();
    let expected = splineface::structure::from_ibug68(&ibug).unwrap();
    for ((m, b), e) in moved.iter().zip(reference.structure()).zip(&expected) {
        assert!(((m - b) - e.coords).norm() < 1e-12);
    }
}

#[test]
fn the_landmark_fit_recovers_weights_and_pose() {
    let space = space();
    let truth = [0.8, -1.3, 0.5];
    let placement = Similarity3::from_parts(
        Translation3::new(3.0, -2.0, 10.0),
        UnitQuaternion::from_euler_angles(0.1, -0.2, 0.05),
        1.3,
    );
    let target: Vec<Point3<f64>> = space
        .structure(&truth)
        .unwrap()
        .iter()
        .map(|p| placement * p)
        .collect();
    // A tiny noise: the prior barely acts.
    let fit = space.fit_structure(&target, &[1.0; POINT_COUNT], 1e-6).unwrap();
    for (w, t) in fit.weights.iter().zip(&truth) {
        assert!((w - t).abs() < 1e-6, "{:?}", fit.weights);
    }
    assert!(fit.rms < 1e-6, "{}", fit.rms);
    assert!((fit.placement.scaling() - 1.3).abs() < 1e-6);
    // A huge noise: the prior wins, weights go to zero.
    let fit = space.fit_structure(&target, &[1.0; POINT_COUNT], 1e6).unwrap();
    assert!(fit.weights.iter().all(|w| w.abs() < 1e-3), "{:?}", fit.weights);
}

#[test]
fn the_dense_fit_recovers_a_member_from_its_mesh() {
    let (mesh, reference) = fixture();
    let space = space();
    let truth = [0.5, -0.8, 0.6];
    let fields = fields(mesh);
    let displaced: Vec<Point3<f64>> = mesh
        .positions()
        .iter()
        .enumerate()
        .map(|(v, p)| {
            p + fields
                .iter()
                .zip(&truth)
                .map(|(f, w)| f[v] * *w)
                .sum::<Vector3<f64>>()
        })
        .collect();
    let target = TriangleMesh::new(displaced, mesh.triangles().to_vec()).unwrap();
    // Start from the landmark fit of a structure with the wrong weights.
    let start_structure = space.structure(&[0.0, 0.0, 0.0]).unwrap();
    let start = space
        .fit_structure(&start_structure, &[1.0; POINT_COUNT], 1.0)
        .unwrap();
    let options = DenseFitOptions {
        noise: 1e-3,
        iterations: 30,
        ..DenseFitOptions::default()
    };
    let fit = space.fit_surface(reference, &target, &start, &options).unwrap();
    // Modes 0 and 2 move the surface along its normal and are recovered; mode 1 slides it
    // within itself (x by a function of y on a height field), which no distance to the
    // surface can see: the fit only has to find the same surface.
    for k in [0, 2] {
        assert!(
            (fit.weights[k] - truth[k]).abs() < 0.05,
            "{:?} against {truth:?}",
            fit.weights
        );
    }
    assert!(fit.rms < 0.1, "{}", fit.rms);
}

#[test]
fn mismatched_inputs_are_refused() {
    let (mesh, reference) = fixture();
    let lm = landmarks(mesh);
    let f = fields(mesh);
    let build = |mesh: &TriangleMesh, lm: &[usize], f: &[Vec<Vector3<f64>>], s: &[f64]| {
        FaceSpace::from_displacements(reference, mesh, lm, f, s)
    };
    let space_error = |r: Result<FaceSpace, FaceError>, needle: &str| match r {
        Err(FaceError::Space(m)) => assert!(m.contains(needle), "{m}"),
        other => panic!("expected a face-space error about {needle}, got {other:?}"),
    };
    space_error(build(mesh, &lm[..67], &f, &[1.0; 3]), "landmark");
    space_error(build(mesh, &lm, &f, &[1.0; 2]), "deviations");
    space_error(build(mesh, &lm, &f, &[1.0, 0.0, 1.0]), "deviation 0");
    let mut short = f.clone();
    short[1].pop();
    space_error(build(mesh, &lm, &short, &[1.0; 3]), "mode 1");
    let mut nan = f.clone();
    nan[2][5].x = f64::NAN;
    space_error(build(mesh, &lm, &nan, &[1.0; 3]), "not finite");
    let lifted = mesh.transformed(&nalgebra::Affine3::from_matrix_unchecked(
        nalgebra::Translation3::new(0.0, 0.0, 20.0).to_homogeneous(),
    ));
    space_error(build(&lifted, &lm, &f, &[1.0; 3]), "not the scan");
    let space = space();
    assert!(space.structure(&[1.0]).is_err());
    assert!(matches!(
        space.fit_structure(&space.structure(&[0.0; 3]).unwrap(), &[1.0; POINT_COUNT], 0.0),
        Err(FaceError::Option { .. })
    ));
}

#[test]
fn the_photo_fit_recovers_weights_and_poses_from_projections() {
    use nalgebra::Point2;
    use splineface::depth::Pose;
    let space = space();
    let truth = [0.8, -1.3, 0.5];
    let shape = space.structure(&truth).unwrap();
    let poses = [
        Pose::from_yaw_pitch_roll_degrees(-35.0, 5.0, 3.0, 4.0),
        Pose::from_yaw_pitch_roll_degrees(0.0, -10.0, -5.0, 3.0),
        Pose::from_yaw_pitch_roll_degrees(40.0, 8.0, 0.0, 5.0),
    ];
    let offsets = [
        Point2::new(200.0, -100.0),
        Point2::new(-50.0, 20.0),
        Point2::new(0.0, 300.0),
    ];
    let views: Vec<Vec<Point2<f64>>> = poses
        .iter()
        .zip(&offsets)
        .map(|(pose, o)| shape.iter().map(|p| o + pose.project(p).coords).collect())
        .collect();
    let fit = space
        .fit_photos(&views, &[1.0; POINT_COUNT], &neutral(1e-6))
        .unwrap();
    for (w, t) in fit.weights.iter().zip(&truth) {
        assert!((w - t).abs() < 1e-4, "{:?} against {truth:?}", fit.weights);
    }
    for (((pose, offset), truth_pose), truth_offset) in fit.poses.iter().zip(&poses).zip(&offsets) {
        assert!(pose.angle_to_degrees(truth_pose) < 1e-3);
        assert!((pose.scale - truth_pose.scale).abs() < 1e-5);
        assert!((offset - truth_offset).norm() < 1e-3);
    }
    assert!(fit.rms_units.iter().all(|r| *r < 1e-5), "{:?}", fit.rms_units);
    // A huge noise keeps the prior's mean.
    let fit = space
        .fit_photos(&views, &[1.0; POINT_COUNT], &neutral(1e6))
        .unwrap();
    assert!(fit.weights.iter().all(|w| w.abs() < 1e-3), "{:?}", fit.weights);
    // Bad input.
    assert!(matches!(
        space.fit_photos(&[], &[1.0; POINT_COUNT], &neutral(1.0)),
        Err(FaceError::Option { .. })
    ));
    assert!(matches!(
        space.fit_photos(&views, &[0.0; POINT_COUNT], &neutral(1.0)),
        Err(FaceError::Option { .. })
    ));
}

/// The embedded space is ICT-FaceKit's identity space: its structure of `w` is the one ICT's
/// own vertices give (exactly), and its surface of `w` lies on ICT's mesh of `w` to within the
/// reference's own fitting residual.
#[test]
#[ignore = "needs ../shared/data/ict-face (not part of the repository)"]
fn the_embedded_space_is_ictfacekits_identity_space() {
    use splineface::landmarks::read_vertex_indices;
    use splineface::mesh::{ClosestPoints, read_mesh};
    use splineface::structure::{from_ibug68, unify};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-face");
    let neutral = read_mesh(&dir.join("neutral_face.obj")).unwrap();
    let n = neutral.positions().len();
    let landmarks = read_vertex_indices(&dir.join("landmarks68.txt"), 68, n).unwrap();
    let bytes = std::fs::read(dir.join("identities.f32")).unwrap();
    let identities: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let ibug: Vec<Point3<f64>> = landmarks.iter().map(|&i| neutral.positions()[i]).collect();
    let (to_canonical, _) = unify(&from_ibug68(&ibug).unwrap()).unwrap();
    let reference = ReferenceFace::embedded();
    let space = reference.face_space().unwrap();
    let mut rng = crate::common::Lcg(5);
    let w: Vec<f64> = (0..60).map(|_| rng.gaussian()).collect();
    let positions: Vec<Point3<f64>> = (0..n)
        .map(|v| {
            let offset: Vector3<f64> = (0..60)
                .map(|k| {
                    let m = &identities[(k * n + v) * 3..(k * n + v) * 3 + 3];
                    Vector3::new(f64::from(m[0]), f64::from(m[1]), f64::from(m[2])) * w[k]
                })
                .sum();
            to_canonical * (neutral.positions()[v] + offset)
        })
        .collect();
    let ibug: Vec<Point3<f64>> = landmarks.iter().map(|&i| positions[i]).collect();
    let expected = from_ibug68(&ibug).unwrap();
    for (a, b) in space.structure(&w).unwrap().iter().zip(&expected) {
        assert!((a - b).norm() < 1e-9, "{a} vs {b}");
    }
    let mesh = TriangleMesh::new(positions, neutral.triangles().to_vec()).unwrap();
    let closest = ClosestPoints::new(&mesh);
    let member = space.surfaces().surface(&w).unwrap();
    let mut distances = Vec::new();
    for i in 0..=40 {
        for j in 0..=40 {
            let (u, v) = (i as f64 / 40.0, j as f64 / 40.0);
            if reference.in_face_region(u, v) {
                distances.push(closest.closest(&member.eval(u, v).unwrap()).distance);
            }
        }
    }
    distances.sort_by(f64::total_cmp);
    let median = distances[distances.len() / 2];
    // The reference's own grid lies within its fit's residuals of the mean face; a member
    // should be as close to its mesh (a few hundredths of a unit), far below a unit.
    assert!(
        median < 0.1,
        "median {median} (the reference fit's: {})",
        reference.fit().median
    );
}

/// Landmarks that ask for an implausible face (a mode at 10σ) get the mode held at 3σ, named.
#[test]
fn implausible_weights_are_held_at_the_priors_edge_and_named() {
    use nalgebra::Point2;
    use splineface::depth::Pose;
    use splineface::face::PLAUSIBLE_SIGMAS;
    let space = space();
    let shape = space.structure(&[0.5, 0.0, 10.0]).unwrap();
    let views: Vec<Vec<Point2<f64>>> = [-30.0, 0.0, 30.0]
        .iter()
        .map(|&yaw| {
            let pose = Pose::from_yaw_pitch_roll_degrees(yaw, 0.0, 0.0, 4.0);
            shape.iter().map(|p| pose.project(p)).collect()
        })
        .collect();
    let fit = space
        .fit_photos(&views, &[1.0; POINT_COUNT], &neutral(1e-6))
        .unwrap();
    assert_eq!(fit.held, vec![2]);
    assert!(
        (fit.weights[2] - PLAUSIBLE_SIGMAS).abs() < 1e-12,
        "{:?}",
        fit.weights
    );
    assert!((fit.weights[0] - 0.5).abs() < 1e-3, "{:?}", fit.weights);
}

/// The expressive space's two expression fields: a smile-like lift of the face's sides and a
/// bulge growing down the face (neither a similarity nor an identity field).
fn expression_fields(mesh: &TriangleMesh) -> Vec<Vec<Vector3<f64>>> {
    type Field = fn(&Point3<f64>) -> Vector3<f64>;
    let f: [Field; 2] = [
        |p| Vector3::new(0.0, 0.002 * p.x * p.x, 0.0),
        |p| Vector3::new(0.0, 0.0, 0.0015 * p.y * p.y),
    ];
    f.iter()
        .map(|f| mesh.positions().iter().map(f).collect())
        .collect()
}

/// The synthetic space with two expression modes, "smile" and "bulge" ([`expression_fields`]).
fn expressive_space() -> FaceSpace {
    let (mesh, reference) = fixture();
    let names = ["smile".to_owned(), "bulge".to_owned()];
    space()
        .with_expression_displacements(
            reference,
            mesh,
            &landmarks(mesh),
            &names,
            &expression_fields(mesh),
            "test",
        )
        .unwrap()
}

#[test]
fn the_space_moves_the_scans_68_landmarks_with_its_modes() {
    let (mesh, reference) = fixture();
    let space = expressive_space();
    let lm = landmarks(mesh);
    let (identity, expression) = (fields(mesh), expression_fields(mesh));
    let (w, e) = ([0.5, -0.8, 0.3], [0.6, 0.2]);
    let got = space
        .landmarks(&w, &e)
        .unwrap()
        .expect("a space from fields carries them");
    for (k, &v) in lm.iter().enumerate() {
        let mut expected = mesh.positions()[v];
        for (f, c) in identity.iter().zip(&w).chain(expression.iter().zip(&e)) {
            expected += f[v] * *c;
        }
        assert!(
            (got[k] - expected).norm() < 1e-12,
            "landmark {k}: {} against {expected}",
            got[k]
        );
    }
    // Through the file (f32 displacements) and back.
    let stored = reference
        .clone()
        .with_space(Some(space.to_modes("test")))
        .unwrap();
    let read = ReferenceFace::from_json(&stored.to_json()).unwrap();
    let again = read.face_space().unwrap().landmarks(&w, &e).unwrap().unwrap();
    for (a, b) in again.iter().zip(&got) {
        assert!((a - b).norm() < 1e-5, "{a} against {b}");
    }
    // A space stored without them (as format version 4 stored spaces) has none.
    let mut modes = space.to_modes("test");
    modes.landmark_base.clear();
    modes.landmarks.clear();
    modes.expressions.landmarks.clear();
    let without = reference.clone().with_space(Some(modes)).unwrap();
    assert_eq!(without.face_space().unwrap().landmarks(&w, &e).unwrap(), None);
}

/// The fixture's space with one expression, "part": the lower inner lip (iBUG 65–67) moved
/// down by 3 units, and nothing else; none of the 40 points moves.
fn parting_space() -> FaceSpace {
    let (mesh, reference) = fixture();
    let lm = landmarks(mesh);
    let part: Vec<Vector3<f64>> = (0..mesh.positions().len())
        .map(|v| {
            if lm[65..68].contains(&v) {
                Vector3::new(0.0, -3.0, 0.0)
            } else {
                Vector3::zeros()
            }
        })
        .collect();
    space()
        .with_expression_displacements(reference, mesh, &lm, &["part".to_owned()], &[part], "test")
        .unwrap()
}

/// Views of `space`'s member `identity` with `expression` in every photo, and each photo's
/// inner-lip gaps, from six poses.
#[allow(clippy::type_complexity)]
fn views_and_gaps(
    space: &FaceSpace,
    identity: &[f64],
    expression: &[f64],
) -> (
    Vec<Vec<nalgebra::Point2<f64>>>,
    Vec<Option<splineface::face::LipGaps>>,
) {
    use splineface::depth::Pose;
    let shape = space.structure_with_expression(identity, expression).unwrap();
    let lm = space.landmarks(identity, expression).unwrap().unwrap();
    (0..6)
        .map(|i| {
            let pose =
                Pose::from_yaw_pitch_roll_degrees(-40.0 + 16.0 * i as f64, 4.0 * (i % 3) as f64, 2.0, 3.0);
            let points = shape.iter().map(|p| pose.project(p)).collect();
            let gaps = splineface::structure::INNER_LIP_PAIRS
                .map(|(upper, lower)| pose.project(&lm[lower]) - pose.project(&lm[upper]));
            (points, Some(gaps))
        })
        .unzip()
}

#[test]
fn the_inner_lips_show_an_expression_the_forty_points_cannot() {
    let space = parting_space();
    let identity = [0.5, -0.8, 0.3];
    let (views, gaps) = views_and_gaps(&space, &identity, &[0.6]);
    let options = PhotoFitOptions {
        noise: 1e-6,
        expressions: Some(ExpressionPrior::independent(1e3)),
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    };
    let weights = [1.0; POINT_COUNT];
    let with = space
        .fit_photos_with_lips(&views, &gaps, &weights, &options)
        .unwrap();
    for (w, t) in with.weights.iter().zip(&identity) {
        assert!((w - t).abs() < 1e-4, "{:?} against {identity:?}", with.weights);
    }
    assert!(
        with.expressions.iter().all(|e| (e[0] - 0.6).abs() < 1e-4),
        "{:?}",
        with.expressions
    );
    // Without the gaps nothing shows the parted lips.
    let without = space.fit_photos(&views, &weights, &options).unwrap();
    assert!(
        without.expressions.iter().all(|e| e[0].abs() < 1e-9),
        "{:?}",
        without.expressions
    );
    // A gap weight of zero is the fit without gaps, to the last digit.
    let zero = PhotoFitOptions { lips: 0.0, ..options };
    assert_eq!(
        space
            .fit_photos_with_lips(&views, &gaps, &weights, &zero)
            .unwrap(),
        without
    );
    // Photos without gaps (a landmarker of 40 points) beside photos with them: each photo's
    // expression comes from its own gaps.
    let mixed: Vec<_> = gaps
        .iter()
        .enumerate()
        .map(|(i, g)| g.filter(|_| i % 2 == 0))
        .collect();
    let fit = space
        .fit_photos_with_lips(&views, &mixed, &weights, &options)
        .unwrap();
    for (i, e) in fit.expressions.iter().enumerate() {
        let expected = if i % 2 == 0 { 0.6 } else { 0.0 };
        assert!((e[0] - expected).abs() < 1e-4, "{:?}", fit.expressions);
    }
    for (w, t) in fit.weights.iter().zip(&identity) {
        assert!((w - t).abs() < 1e-4, "{:?} against {identity:?}", fit.weights);
    }
}

#[test]
fn bad_inner_lip_gaps_are_refused() {
    let space = parting_space();
    let (views, gaps) = views_and_gaps(&space, &[0.0; 3], &[0.3]);
    let options = PhotoFitOptions {
        noise: 1.0,
        expressions: Some(ExpressionPrior::DEFAULT),
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    };
    let weights = [1.0; POINT_COUNT];
    let refused =
        |gaps: &[Option<splineface::face::LipGaps>], options: &PhotoFitOptions, needle: &str| match space
            .fit_photos_with_lips(&views, gaps, &weights, options)
        {
            Err(e @ FaceError::Option { .. }) => assert!(e.to_string().contains(needle), "{e}"),
            other => panic!("expected an option error about {needle}, got {other:?}"),
        };
    refused(&gaps[..5], &options, "one entry per view");
    let mut nan = gaps.clone();
    nan[3].as_mut().unwrap()[1].y = f64::NAN;
    refused(&nan, &options, "view 3");
    refused(
        &gaps,
        &PhotoFitOptions {
            lips: -1.0,
            ..options
        },
        "lip weight",
    );
    refused(
        &gaps,
        &PhotoFitOptions {
            lips: f64::INFINITY,
            ..options
        },
        "lip weight",
    );
}

/// `n` views of the expressive space's member `identity` wearing `expression` in every photo,
/// turned from −40° to 40°.
fn views_with_expression(
    space: &FaceSpace,
    identity: &[f64],
    expression: &[f64],
    n: usize,
) -> Vec<Vec<nalgebra::Point2<f64>>> {
    use splineface::depth::Pose;
    let shape = space.structure_with_expression(identity, expression).unwrap();
    (0..n)
        .map(|i| {
            let yaw = -40.0 + 80.0 * i as f64 / (n - 1) as f64;
            let pose = Pose::from_yaw_pitch_roll_degrees(yaw, 5.0 * (i % 3) as f64 - 5.0, 0.0, 3.0);
            shape.iter().map(|p| pose.project(p)).collect()
        })
        .collect()
}

/// The fitted expression weight `mode` in every photo.
fn fitted(
    space: &FaceSpace,
    views: &[Vec<nalgebra::Point2<f64>>],
    noise: f64,
    prior: ExpressionPrior,
    mode: usize,
) -> Vec<f64> {
    let options = PhotoFitOptions {
        noise,
        expressions: Some(prior),
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    };
    let fit = space.fit_photos(views, &[1.0; POINT_COUNT], &options).unwrap();
    fit.expressions.iter().map(|e| e[mode]).collect()
}

#[test]
fn a_shared_expression_keeps_a_smile_that_every_photo_shows() {
    // Eight photos that all smile, under a prior tight enough to matter: independent, the
    // smile pays its prior eight times and the fit shrinks it; around a shared expression it
    // pays about once.
    let space = expressive_space();
    let views = views_with_expression(&space, &[0.5, -0.8, 0.3], &[0.6, 0.0], 8);
    let independent = fitted(&space, &views, 5.0, ExpressionPrior::independent(0.5), 0);
    let shared = fitted(
        &space,
        &views,
        5.0,
        ExpressionPrior {
            shared_sigma: Some(0.5),
            ..ExpressionPrior::independent(0.5)
        },
        0,
    );
    let error = |found: &[f64]| found.iter().map(|e| (e - 0.6).abs()).sum::<f64>() / found.len() as f64;
    assert!(
        error(&shared) < 0.5 * error(&independent),
        "shared {shared:?} against independent {independent:?}"
    );
}

#[test]
fn the_expression_rate_keeps_a_weight_at_zero_until_the_points_pull_harder() {
    // A faint smile in every photo: the plain prior fits it, the rate leaves it at exactly zero;
    // a clear smile still comes through the rate, shrunk by little.
    let space = expressive_space();
    let rated = ExpressionPrior {
        rate: 1.0,
        ..ExpressionPrior::independent(0.5)
    };
    let faint = views_with_expression(&space, &[0.5, -0.8, 0.3], &[0.01, 0.0], 8);
    let plain = fitted(&space, &faint, 1.0, ExpressionPrior::independent(0.5), 0);
    assert!(plain.iter().all(|e| *e > 0.005), "{plain:?}");
    let with_rate = fitted(&space, &faint, 1.0, rated, 0);
    assert!(with_rate.iter().all(|e| *e == 0.0), "{with_rate:?}");
    let clear = views_with_expression(&space, &[0.5, -0.8, 0.3], &[0.6, 0.0], 8);
    let with_rate = fitted(&space, &clear, 1.0, rated, 0);
    assert!(with_rate.iter().all(|e| (0.5..0.6).contains(e)), "{with_rate:?}");
}

#[test]
fn the_photo_fit_separates_a_shared_identity_from_each_photos_expression() {
    use nalgebra::Point2;
    use splineface::depth::Pose;
    let space = expressive_space();
    assert_eq!(space.expressions().names, ["smile", "bulge"]);
    let identity = [0.5, -0.8, 0.3];
    let expressions = [[0.6, 0.0], [0.2, 0.7], [0.0, 0.4], [0.9, 0.9]];
    let poses = [
        Pose::from_yaw_pitch_roll_degrees(-35.0, 5.0, 3.0, 4.0),
        Pose::from_yaw_pitch_roll_degrees(0.0, -10.0, -5.0, 3.0),
        Pose::from_yaw_pitch_roll_degrees(40.0, 8.0, 0.0, 5.0),
        Pose::from_yaw_pitch_roll_degrees(15.0, 20.0, 8.0, 2.0),
    ];
    let views: Vec<Vec<Point2<f64>>> = poses
        .iter()
        .zip(&expressions)
        .map(|(pose, e)| {
            let shape = space.structure_with_expression(&identity, e).unwrap();
            shape
                .iter()
                .map(|p| Point2::new(100.0, 50.0) + pose.project(p).coords)
                .collect()
        })
        .collect();
    let options = PhotoFitOptions {
        noise: 1e-6,
        expressions: Some(ExpressionPrior {
            sigma: 1e3,
            ..ExpressionPrior::DEFAULT
        }),
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    };
    let fit = space.fit_photos(&views, &[1.0; POINT_COUNT], &options).unwrap();
    for (w, t) in fit.weights.iter().zip(&identity) {
        assert!((w - t).abs() < 1e-4, "{:?} against {identity:?}", fit.weights);
    }
    assert_eq!(fit.expression_names, ["smile", "bulge"]);
    for (found, truth) in fit.expressions.iter().zip(&expressions) {
        for (f, t) in found.iter().zip(truth) {
            assert!(
                (f - t).abs() < 1e-4,
                "{:?} against {expressions:?}",
                fit.expressions
            );
        }
    }
    for ((pose, _), truth) in fit.poses.iter().zip(&poses) {
        assert!(pose.angle_to_degrees(truth) < 1e-3);
        assert!((pose.scale / truth.scale - 1.0).abs() < 1e-5);
    }
    assert!(fit.rms_units.iter().all(|r| *r < 1e-5), "{:?}", fit.rms_units);
    // Without expressions the same photos leave residuals, and the identity absorbs what it can.
    let neutral_fit = space
        .fit_photos(&views, &[1.0; POINT_COUNT], &neutral(1e-6))
        .unwrap();
    assert!(neutral_fit.expressions.iter().all(Vec::is_empty));
    assert!(
        neutral_fit.rms_units.iter().any(|r| *r > 0.1),
        "{:?}",
        neutral_fit.rms_units
    );
    // An expression the photo does not show in its positive range stays at the bound: a
    // frown (the smile at −0.5) is not a smile.
    let frown = space.structure(&identity).unwrap();
    let smile = &space.expressions().structure[0];
    let views: Vec<Vec<Point2<f64>>> = poses
        .iter()
        .map(|pose| {
            frown
                .iter()
                .zip(smile)
                .map(|(p, d)| pose.project(&(p - d * 0.5)))
                .collect()
        })
        .collect();
    let fit = space.fit_photos(&views, &[1.0; POINT_COUNT], &options).unwrap();
    assert!(
        fit.expressions.iter().all(|e| e[0] == 0.0),
        "{:?}",
        fit.expressions
    );
    // The face with an expression: its structure is the member's, and no expression is the
    // neutral face.
    let (_, reference) = fixture();
    let face = space
        .face_with_expression(reference, &identity, &[0.6, 0.0])
        .unwrap();
    assert_eq!(
        face.structure(),
        &space.structure_with_expression(&identity, &[0.6, 0.0]).unwrap()[..]
    );
    assert_eq!(
        space
            .face_with_expression(reference, &identity, &[])
            .unwrap()
            .surface(),
        space.face(reference, &identity).unwrap().surface()
    );
    // Bad options.
    for prior in [
        ExpressionPrior::independent(0.0),
        ExpressionPrior {
            shared_sigma: Some(f64::NAN),
            ..ExpressionPrior::DEFAULT
        },
        ExpressionPrior {
            rate: -1.0,
            ..ExpressionPrior::DEFAULT
        },
    ] {
        let bad = PhotoFitOptions {
            noise: 1.0,
            expressions: Some(prior),
            outline: false,
            lips: splineface::face::LIP_WEIGHT,
        };
        assert!(
            matches!(
                space.fit_photos(&views, &[1.0; POINT_COUNT], &bad),
                Err(FaceError::Option { .. })
            ),
            "{prior:?}"
        );
    }
    // Names must be one per field.
    let (mesh, reference) = fixture();
    let err = space
        .clone()
        .with_expression_displacements(reference, mesh, &landmarks(mesh), &["x".to_owned()], &[], "")
        .unwrap_err();
    assert!(
        err.to_string().contains("1 expression names for 0 fields"),
        "{err}"
    );
}

/// A face round enough to have an outline: a vertical cylinder of radius 61 (the jaw points,
/// 57 units out, lie where it slopes at 69°), zero at the eye centres, and the reference fitted
/// to it.
fn round_fixture() -> &'static (TriangleMesh, ReferenceFace) {
    static FIXTURE: OnceLock<(TriangleMesh, ReferenceFace)> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let radius: f64 = 61.0;
        let height = move |x: f64, _: f64| {
            (radius * radius - x * x).max(0.0).sqrt() - (radius * radius - 625.0).sqrt()
        };
        let scan = crate::reference::height_field_scan(height, -61.0..=61.0, -120.0..=70.0, 121);
        let reference =
            build_reference(std::slice::from_ref(&scan), &ReferenceOptions::default(), "test").unwrap();
        (scan.mesh, reference)
    })
}

/// [`landmarks`] with the jaw points off the chin at the scan's vertices nearest the
/// structure's: their modes are then the surface's own displacement there, as a real
/// space's are (its landmark vertices lie on its scan).
fn jaw_landmarks(mesh: &TriangleMesh, reference: &ReferenceFace) -> Vec<usize> {
    let mut ibug = landmarks(mesh);
    for &j in &splineface::face::OUTLINE_POINTS {
        let point = reference.structure()[j];
        let nearest = (0..mesh.positions().len())
            .min_by(|&a, &b| {
                let d = |k: usize| (mesh.positions()[k] - point).norm();
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        ibug[splineface::structure::POINTS[j].ibug_sources[0]] = nearest;
    }
    ibug
}

/// How far a landmarker sees a jaw point `point` of a face moved along the face's surface
/// `surface` (a height field over `reference`'s frame, as members of a space on it are)
/// onto its outline, by brute force: along the surface's line at the point's height, from
/// the point in to the middle of the face, the place the camera `pose` sees farthest toward
/// the point's side, less the point's own place.
fn outline_move(
    surface: &splineface::bspline::BSplineSurface,
    reference: &ReferenceFace,
    point: &Point3<f64>,
    pose: &splineface::depth::Pose,
) -> Vector3<f64> {
    let n = 4000;
    let rows = pose.rotation.matrix().fixed_rows::<2>(0).into_owned();
    let axis = rows * Vector3::x();
    let side = point.x.signum();
    let start = reference.frame().parameters(point.x, point.y);
    let along = |k: usize| {
        let u = start.x + (0.5 - start.x) * k as f64 / n as f64;
        surface.eval(u, start.y).unwrap()
    };
    let outline = (0..n)
        .map(along)
        .max_by(|a, b| {
            (side * (rows * a.coords).dot(&axis)).total_cmp(&(side * (rows * b.coords).dot(&axis)))
        })
        .unwrap();
    outline - along(0)
}

#[test]
fn the_photo_fit_measures_the_jaw_against_the_faces_outline() {
    use nalgebra::Point2;
    use splineface::depth::Pose;
    use splineface::face::OUTLINE_POINTS;
    let (mesh, reference) = round_fixture();
    let space = FaceSpace::from_displacements(
        reference,
        mesh,
        &jaw_landmarks(mesh, reference),
        &fields(mesh),
        &[1.0, 1.0, 1.0],
    )
    .unwrap();
    let truth = [0.8, -1.3, 0.5];
    let shape = space.structure(&truth).unwrap();
    let member = space.surfaces().surface(&truth).unwrap();
    // Turned enough that on the side turned away the outline lies well inside the jaw points.
    let poses = [
        Pose::from_yaw_pitch_roll_degrees(-35.0, 5.0, 3.0, 4.0),
        Pose::from_yaw_pitch_roll_degrees(0.0, -10.0, -5.0, 3.0),
        Pose::from_yaw_pitch_roll_degrees(40.0, 8.0, 0.0, 5.0),
        Pose::from_yaw_pitch_roll_degrees(25.0, -4.0, 2.0, 4.5),
    ];
    let mut moved: f64 = 0.0;
    let views: Vec<Vec<Point2<f64>>> = poses
        .iter()
        .map(|pose| {
            let mut seen = shape.clone();
            for &j in &OUTLINE_POINTS {
                seen[j] += outline_move(&member, reference, &reference.structure()[j], pose);
                moved = moved.max((pose.project(&seen[j]) - pose.project(&shape[j])).norm());
            }
            seen.iter().map(|p| pose.project(p)).collect()
        })
        .collect();
    assert!(moved > 8.0, "the outline moves a jaw point {moved} px only");
    let options = |outline| PhotoFitOptions {
        noise: 1e-3,
        expressions: None,
        outline,
        lips: splineface::face::LIP_WEIGHT,
    };
    let error = |fit: &splineface::face::PhotoSpaceFit| {
        fit.weights
            .iter()
            .zip(&truth)
            .map(|(w, t)| (w - t).abs())
            .fold(0.0, f64::max)
    };
    let weights = [1.0; POINT_COUNT];
    let with = space.fit_photos(&views, &weights, &options(true)).unwrap();
    let without = space.fit_photos(&views, &weights, &options(false)).unwrap();
    // Measured: 0.002 with the outline (its lines' samples lie about half a unit apart),
    // 0.057 without.
    assert!(error(&with) < 0.01, "{:?} against {truth:?}", with.weights);
    assert!(error(&without) > 0.03, "{:?}", without.weights);
    assert!(with.rms_units.iter().all(|r| *r < 0.05), "{:?}", with.rms_units);
    assert!(
        without.rms_units.iter().any(|r| *r > 0.2),
        "{:?}",
        without.rms_units
    );
    assert!(without.outline_shifts.is_empty());
    // The shifts move the outline points only, and the fitted points then lie on the photos'
    // (within a pixel, a fifth of a unit: the shifts were found before the last round).
    for ((shifts, view), (pose, offset)) in with.outline_shifts.iter().zip(&views).zip(&with.poses) {
        for (j, s) in shifts.iter().enumerate() {
            assert!(OUTLINE_POINTS.contains(&j) || s.norm() == 0.0);
            let seen = offset + pose.project(&shape[j]).coords - s;
            assert!(
                (seen - view[j]).norm() < 1.0,
                "point {j}: {seen} against {}",
                view[j]
            );
        }
    }
}
