//! Depth by pose/depth alternation, on structures the tests make and see under known poses.

use nalgebra::{Point2, Point3};
use proptest::prelude::*;
use splineface::Real;
use splineface::align::{AlignError, FrontalStructure, PhotoPoints, procrustes_frontal};
use splineface::depth::{
    DepthError, DepthEstimate, DepthOptions, DepthWarning, FrontalFreedom, FrontalGauge, Pose,
    StructurePrior, estimate_depth,
};
use splineface::reference::ReferenceFace;
use splineface::structure::{LEFT_EYE_CENTRE, POINTS, RIGHT_EYE_CENTRE, correlation};

use crate::common::Lcg;

/// A face that is not the reference: deeper, longer, slightly asymmetric, eye centres still at
/// `(±25, 0, 0)` (the canonical frame).
pub fn truth() -> Vec<Point3<Real>> {
    ReferenceFace::embedded()
        .structure()
        .iter()
        .enumerate()
        .map(|(k, p)| {
            if k == RIGHT_EYE_CENTRE || k == LEFT_EYE_CENTRE {
                return *p;
            }
            let bump = 2.0 * (p.x / 15.0).sin() * (p.y / 30.0).cos();
            Point3::new(p.x, 1.08 * p.y, 1.25 * p.z + bump)
        })
        .collect()
}

/// A random pose within the ranges: yaw ±60°, pitch ±25°, roll ±15°, 2–6 px a unit.
fn random_pose(rng: &mut Lcg) -> Pose {
    Pose::from_yaw_pitch_roll_degrees(
        rng.uniform(-60.0, 60.0),
        rng.uniform(-25.0, 25.0),
        rng.uniform(-15.0, 15.0),
        rng.uniform(2.0, 6.0),
    )
}

/// The structure seen under `pose`, placed in a 640 × 480 image (`v` down), with Gaussian noise
/// of `noise` eye distances (scaled by the pose's pixels per eye distance).
fn view(structure: &[Point3<Real>], pose: &Pose, noise: Real, rng: &mut Lcg, name: &str) -> PhotoPoints {
    let sigma = noise * 50.0 * pose.scale;
    let (cx, cy) = (rng.uniform(250.0, 390.0), rng.uniform(180.0, 300.0));
    let pixels = structure
        .iter()
        .map(|p| {
            let q = pose.project(p);
            Point2::new(
                cx + q.x + sigma * rng.gaussian(),
                cy - q.y + sigma * rng.gaussian(),
            )
        })
        .collect();
    PhotoPoints::new(name, pixels).unwrap()
}

struct Scene {
    truth: Vec<Point3<Real>>,
    poses: Vec<Pose>,
    photos: Vec<PhotoPoints>,
}

fn scene(count: usize, noise: Real, seed: u64) -> Scene {
    let mut rng = Lcg(seed);
    let truth = truth();
    let poses: Vec<Pose> = (0..count).map(|_| random_pose(&mut rng)).collect();
    let photos = poses
        .iter()
        .enumerate()
        .map(|(k, pose)| view(&truth, pose, noise, &mut rng, &format!("photo{k}")))
        .collect();
    Scene { truth, poses, photos }
}

fn run(scene: &Scene, options: &DepthOptions) -> (FrontalStructure, DepthEstimate) {
    let frontal = procrustes_frontal(&scene.photos).unwrap();
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    let estimate = estimate_depth(&scene.photos, &frontal, &prior, options).unwrap();
    (frontal, estimate)
}

/// Depths of the 38 points other than the (pinned) eye centres.
fn free_depths(points: &[Point3<Real>]) -> Vec<Real> {
    points
        .iter()
        .enumerate()
        .filter(|&(k, _)| k != RIGHT_EYE_CENTRE && k != LEFT_EYE_CENTRE)
        .map(|(_, p)| p.z)
        .collect()
}

fn depth_rms(a: &[Point3<Real>], b: &[Point3<Real>]) -> Real {
    let (x, y) = (free_depths(a), free_depths(b));
    (x.iter().zip(&y).map(|(p, q)| (p - q) * (p - q)).sum::<Real>() / x.len() as Real).sqrt()
}

fn rotation_error_degrees(a: &Pose, b: &Pose) -> Real {
    a.angle_to_degrees(b)
}

#[test]
fn noise_free_views_give_the_depths_and_the_poses_back() {
    for seed in [1, 2, 3] {
        let scene = scene(12, 0.0, seed);
        let (_, estimate) = run(&scene, &DepthOptions::default());
        let r = correlation(&free_depths(&estimate.structure), &free_depths(&scene.truth)).unwrap();
        assert!(r >= 0.99, "seed {seed}: depth correlation {r}");
        for (fit, pose) in estimate.photos.iter().zip(&scene.poses) {
            let error = rotation_error_degrees(&fit.pose, pose);
            assert!(error < 1.0, "seed {seed}, {}: pose off by {error}°", fit.name);
            let relative_scale = fit.pose.scale / pose.scale;
            assert!(
                (relative_scale - 1.0).abs() < 0.02,
                "scale ratio {relative_scale}"
            );
            let [y0, p0, r0] = fit.pose.yaw_pitch_roll_degrees();
            let [y1, p1, r1] = pose.yaw_pitch_roll_degrees();
            assert!((y0 - y1).abs() < 1.0 && (p0 - p1).abs() < 1.0 && (r0 - r1).abs() < 1.0);
        }
        assert!(estimate.converged, "seed {seed}");
        assert!(
            estimate.warnings.is_empty(),
            "seed {seed}: {:?}",
            estimate.warnings
        );
        // The objective never rises much, and ends below where it started.
        assert!(estimate.objective.last().unwrap() < &estimate.objective[0]);
        // The fitted poses put the estimated points back where the photos saw them.
        for (fit, photo) in estimate.photos.iter().zip(&scene.photos) {
            let rms = (estimate
                .structure
                .iter()
                .zip(&photo.points)
                .map(|(p, seen)| (fit.pixel(p) - seen).norm_squared())
                .sum::<Real>()
                / 40.0)
                .sqrt();
            assert!(
                (rms - fit.rms_pixels).abs() < 1e-6 * (1.0 + rms),
                "{}: {rms} vs {}",
                fit.name,
                fit.rms_pixels
            );
            assert!(rms < 0.5, "{}: {rms} px", fit.name);
        }
        let frontal = estimate.most_frontal_photo().unwrap();
        let angle = |k: usize| scene.poses[k].view_angle_degrees();
        assert!((0..12).all(|k| angle(frontal) <= angle(k) + 1.0), "seed {seed}");
    }
}

#[test]
fn the_eye_centres_stay_in_the_canonical_frame() {
    let scene = scene(6, 0.01, 9);
    for frontal_freedom in [FrontalFreedom::Fixed, FrontalFreedom::Gauge, FrontalFreedom::Free] {
        let options = DepthOptions {
            frontal: frontal_freedom,
            ..DepthOptions::default()
        };
        let (frontal, estimate) = run(&scene, &options);
        assert_eq!(estimate.structure[RIGHT_EYE_CENTRE], Point3::new(-25.0, 0.0, 0.0));
        assert_eq!(estimate.structure[LEFT_EYE_CENTRE], Point3::new(25.0, 0.0, 0.0));
        if frontal_freedom == FrontalFreedom::Fixed {
            // The paper's method: x and y are the frontal structure's.
            for (p, f) in estimate.structure.iter().zip(&frontal.points) {
                assert_eq!((p.x, p.y), (f.x, f.y));
            }
            assert_eq!(
                estimate.gauge,
                FrontalGauge {
                    shear: 0.0,
                    stretch: 1.0
                }
            );
        }
    }
}

#[test]
fn the_true_frontal_structure_gives_the_exact_answer_in_every_mode() {
    // An oracle for the machinery: with the true x, y handed in, noise-free photos fix the
    // depths exactly. (Free mode turns the result about the eye axis to fit the reference best,
    // which for this truth is a rotation of about half a degree; the shape is exact.)
    let s = scene(5, 0.0, 21);
    let mut frontal = procrustes_frontal(&s.photos).unwrap();
    frontal.points = s.truth.iter().map(|p| Point2::new(p.x, p.y)).collect();
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    for frontal_freedom in [FrontalFreedom::Fixed, FrontalFreedom::Gauge, FrontalFreedom::Free] {
        let options = DepthOptions {
            frontal: frontal_freedom,
            tolerance: 1e-9,
            ..DepthOptions::default()
        };
        let estimate = estimate_depth(&s.photos, &frontal, &prior, &options).unwrap();
        let shape_error = if frontal_freedom == FrontalFreedom::Free {
            // Compare shapes: edge lengths are unchanged by the turn.
            let edges = prior.edges();
            let a = splineface::structure::edge_lengths(&estimate.structure, edges);
            let b = splineface::structure::edge_lengths(&s.truth, edges);
            a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, Real::max)
        } else {
            estimate
                .structure
                .iter()
                .zip(&s.truth)
                .map(|(p, q)| (p - q).norm())
                .fold(0.0, Real::max)
        };
        assert!(shape_error < 1e-3, "{frontal_freedom:?}: error {shape_error}");
        assert!(estimate.photos.iter().all(|p| p.rms_pixels < 1e-3));
    }
}

#[test]
fn error_grows_smoothly_with_noise_and_the_face_never_flips() {
    let nose_tip = POINTS.iter().position(|d| d.name == "nose_tip").unwrap();
    let right_outer = POINTS.iter().position(|d| d.name == "eye_right_outer").unwrap();
    let levels = [0.0, 0.005, 0.01, 0.02, 0.04];
    let mut errors = Vec::new();
    for &noise in &levels {
        let mut total = 0.0;
        for seed in 0..4 {
            let scene = scene(10, noise, 100 + seed);
            let (_, estimate) = run(&scene, &DepthOptions::default());
            let s = &estimate.structure;
            // A depth-reversed face has its nose behind the eyes; a mirrored one has the
            // subject's right eye on the image's right.
            assert!(
                s[nose_tip].z > 15.0,
                "noise {noise}: nose tip z = {}",
                s[nose_tip].z
            );
            assert!(s[right_outer].x < -25.0, "noise {noise}: mirrored face");
            let r = correlation(&free_depths(s), &free_depths(&scene.truth)).unwrap();
            assert!(r > 0.9, "noise {noise}: correlation {r}");
            total += depth_rms(s, &scene.truth) / 4.0;
        }
        errors.push(total);
    }
    // Noise-free is near exact; then the error grows, and no more than linearly plus the floor.
    assert!(errors[0] < 0.5, "noise-free depth RMS {}", errors[0]);
    for k in 1..levels.len() {
        assert!(
            errors[k] >= errors[k - 1] * 0.9,
            "error fell from {} to {} at noise {}",
            errors[k - 1],
            errors[k],
            levels[k]
        );
        let slope_bound = errors[0] + 200.0 * levels[k];
        assert!(
            errors[k] < slope_bound,
            "noise {}: depth RMS {} ≥ {slope_bound}",
            levels[k],
            errors[k]
        );
    }
    assert!(errors[4] > errors[0] + 0.2, "noise has no effect? {errors:?}");
}

#[test]
fn one_photo_still_gives_a_structure_and_says_so() {
    let scene = scene(1, 0.0, 5);
    let (_, estimate) = run(&scene, &DepthOptions::default());
    assert_eq!(estimate.structure.len(), 40);
    assert!(estimate.structure.iter().all(|p| p.z.is_finite()));
    assert!(
        estimate
            .warnings
            .contains(&DepthWarning::FewPoses { distinct: 1 })
    );
    // Depth is still positive at the nose: the reference start keeps the face the right way out.
    assert!(estimate.structure[28].z > 0.0);
}

#[test]
fn frontal_photos_leave_the_depth_to_the_reference() {
    let mut rng = Lcg(3);
    let truth = truth();
    let photos: Vec<PhotoPoints> = (0..5)
        .map(|k| {
            let pose = Pose::from_yaw_pitch_roll_degrees(0.0, 0.0, rng.uniform(-10.0, 10.0), 3.0);
            view(&truth, &pose, 0.0, &mut rng, &format!("front{k}"))
        })
        .collect();
    let frontal = procrustes_frontal(&photos).unwrap();
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    for similarity_constraint in [true, false] {
        let options = DepthOptions {
            similarity_constraint,
            ..DepthOptions::default()
        };
        let estimate = estimate_depth(&photos, &frontal, &prior, &options).unwrap();
        assert!(
            estimate
                .warnings
                .iter()
                .any(|w| matches!(w, DepthWarning::DepthUnobservable { .. })),
            "{:?}",
            estimate.warnings
        );
        let r = correlation(&free_depths(&estimate.structure), &free_depths(prior.points())).unwrap();
        assert!(r > 0.95, "correlation with the reference {r}");
    }
}

#[test]
fn without_the_similarity_constraint_noise_free_views_are_still_recovered() {
    let scene = scene(12, 0.0, 4);
    let options = DepthOptions {
        similarity_constraint: false,
        ..DepthOptions::default()
    };
    let (_, estimate) = run(&scene, &options);
    let r = correlation(&free_depths(&estimate.structure), &free_depths(&scene.truth)).unwrap();
    assert!(r >= 0.99, "correlation {r}");
}

#[test]
fn a_photo_of_another_face_is_reported() {
    let mut s = scene(8, 0.0, 11);
    // Photo 3's points scrambled: a different "face" altogether.
    let mut rng = Lcg(77);
    let scrambled: Vec<Point2<Real>> = s.photos[3]
        .points
        .iter()
        .map(|p| p + nalgebra::Vector2::new(rng.uniform(-40.0, 40.0), rng.uniform(-40.0, 40.0)))
        .collect();
    s.photos[3] = PhotoPoints::new("stranger", scrambled).unwrap();
    let (_, estimate) = run(&s, &DepthOptions::default());
    let flagged: Vec<&str> = estimate
        .warnings
        .iter()
        .filter_map(|w| match w {
            DepthWarning::BadFit { photo, .. } => Some(photo.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(flagged, ["stranger"], "{:?}", estimate.warnings);
    let message = estimate.warnings[0].to_string();
    assert!(
        message.contains("stranger") && message.contains("badly"),
        "{message}"
    );
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let s = scene(3, 0.0, 1);
    let frontal = procrustes_frontal(&s.photos).unwrap();
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    let options = DepthOptions::default();

    assert!(matches!(
        estimate_depth(&[], &frontal, &prior, &options),
        Err(DepthError::Align(AlignError::NoPhotos))
    ));
    assert_eq!(
        estimate_depth(&s.photos[..2], &frontal, &prior, &options),
        Err(DepthError::PhotoCountMismatch {
            photos: 2,
            frontal: 3
        })
    );
    let mut photos = s.photos.clone();
    photos[1].points[5].x = f64::INFINITY;
    let error = estimate_depth(&photos, &frontal, &prior, &options).unwrap_err();
    assert!(
        error.to_string().contains("photo1") && error.to_string().contains("point 5"),
        "{error}"
    );

    for (tolerance, max_iterations) in [(0.0, 10), (f64::NAN, 10), (-1.0, 10), (0.01, 0)] {
        let bad = DepthOptions {
            tolerance,
            max_iterations,
            ..options
        };
        assert!(matches!(
            estimate_depth(&s.photos, &frontal, &prior, &bad),
            Err(DepthError::Option { .. })
        ));
    }

    let mut moved = frontal.clone();
    moved.points[23].x += 1.0;
    assert!(matches!(
        estimate_depth(&s.photos, &moved, &prior, &options),
        Err(DepthError::Align(AlignError::Frontal { .. }))
    ));

    let points = prior.points().to_vec();
    assert!(StructurePrior::new(points[..39].to_vec(), prior.edges().to_vec()).is_err());
    assert!(StructurePrior::new(points.clone(), vec![]).is_err());
    assert!(StructurePrior::new(points.clone(), vec![[0, 40]]).is_err());
    assert!(StructurePrior::new(points.clone(), vec![[3, 3]]).is_err());
    let mut nan = points;
    nan[2].z = f64::NAN;
    let error = StructurePrior::new(nan, prior.edges().to_vec()).unwrap_err();
    assert_eq!(error.to_string(), "reference structure: point 2 is not finite");
}

#[test]
fn iteration_cap_is_reported() {
    let scene = scene(8, 0.02, 12);
    let options = DepthOptions {
        tolerance: 1e-300,
        max_iterations: 2,
        ..DepthOptions::default()
    };
    let (_, estimate) = run(&scene, &options);
    assert_eq!(estimate.iterations, 2);
    assert!(!estimate.converged);
    assert_eq!(estimate.objective.len(), 3);
    assert!(
        estimate
            .warnings
            .contains(&DepthWarning::NotConverged { iterations: 2 })
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn angles_round_trip(yaw in -89.0..89.0f64, pitch in -89.0..89.0f64, roll in -179.0..179.0f64, scale in 0.1..10.0f64) {
        let pose = Pose::from_yaw_pitch_roll_degrees(yaw, pitch, roll, scale);
        let [y, p, r] = pose.yaw_pitch_roll_degrees();
        prop_assert!((y - yaw).abs() < 1e-9 && (p - pitch).abs() < 1e-9 && (r - roll).abs() < 1e-9);
    }
}

#[test]
fn angle_signs_match_their_documentation() {
    let nose = Point3::new(0.0, 0.0, 10.0);
    // Positive yaw: the nose toward the image's right (+x).
    assert!(
        Pose::from_yaw_pitch_roll_degrees(20.0, 0.0, 0.0, 1.0)
            .project(&nose)
            .x
            > 0.0
    );
    // Positive pitch: the nose down (−y, y up).
    assert!(
        Pose::from_yaw_pitch_roll_degrees(0.0, 20.0, 0.0, 1.0)
            .project(&nose)
            .y
            < 0.0
    );
    // Positive roll: counter-clockwise, so +x turns toward +y.
    assert!(
        Pose::from_yaw_pitch_roll_degrees(0.0, 0.0, 20.0, 1.0)
            .project(&Point3::new(10.0, 0.0, 0.0))
            .y
            > 0.0
    );
    assert!(
        (Pose::from_yaw_pitch_roll_degrees(30.0, 0.0, 0.0, 1.0).view_angle_degrees() - 30.0).abs() < 1e-9
    );
}
