//! The frontal 2D structure from points alone: generalised affine Procrustes.

use nalgebra::{Matrix2, Point2, Vector2};
use proptest::prelude::*;
use splineface::Real;
use splineface::align::{AlignError, FrontalMethod, PhotoPoints, apply_affine, procrustes_frontal};
use splineface::reference::ReferenceFace;
use splineface::structure::{POINTS, StructureError};

/// The reference structure's frontal `(x, y)`.
fn frontal_truth() -> Vec<Point2<Real>> {
    ReferenceFace::embedded()
        .structure()
        .iter()
        .map(|p| Point2::new(p.x, p.y))
        .collect()
}

/// `y`-up points to image pixels (`v` down) through the affine map `x ↦ A x + t`.
fn photo(name: &str, points: &[Point2<Real>], a: Matrix2<Real>, t: Vector2<Real>) -> PhotoPoints {
    let pixels = points
        .iter()
        .map(|p| {
            let q = a * p.coords + t;
            Point2::new(q.x, -q.y)
        })
        .collect();
    PhotoPoints::new(name, pixels).unwrap()
}

fn max_distance(a: &[Point2<Real>], b: &[Point2<Real>]) -> Real {
    a.iter().zip(b).map(|(p, q)| (p - q).norm()).fold(0.0, Real::max)
}

/// The reference's frontal points with unit Gaussian noise (asymmetric sets, not affine images
/// of each other), one photo through each map.
fn noisy_photos(maps: &[(Matrix2<Real>, Vector2<Real>)], seed: u64) -> Vec<PhotoPoints> {
    let truth = frontal_truth();
    let mut rng = crate::common::Lcg(seed);
    maps.iter()
        .enumerate()
        .map(|(k, (a, t))| {
            let noisy: Vec<Point2<Real>> = truth
                .iter()
                .map(|p| p + Vector2::new(rng.gaussian(), rng.gaussian()))
                .collect();
            photo(&format!("p{k}"), &noisy, *a, *t)
        })
        .collect()
}

/// Affine maps with positive determinant and condition number below about 4.
fn affine() -> impl Strategy<Value = (Matrix2<Real>, Vector2<Real>)> {
    (
        0.5..3.0f64,
        0.7..1.4f64,
        -0.3..0.3f64,
        -3.2..3.2f64,
        -500.0..500.0f64,
        -500.0..500.0f64,
    )
        .prop_map(|(scale, aspect, shear, angle, tx, ty)| {
            let rotation = nalgebra::Rotation2::new(angle).into_inner();
            let a = rotation * Matrix2::new(scale * aspect, shear * scale, 0.0, scale / aspect);
            (a, Vector2::new(tx, ty))
        })
}

/// The affine map that carries `from` onto `to` best, and the largest distance left (normal
/// equations on centred points, written independently of the library's).
fn affine_fit_error(from: &[Point2<Real>], to: &[Point2<Real>]) -> Real {
    let n = from.len() as Real;
    let fm = from.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n;
    let tm = to.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n;
    let (mut spread, mut cross) = (Matrix2::zeros(), Matrix2::zeros());
    for (p, q) in from.iter().zip(to) {
        spread += (p.coords - fm) * (p.coords - fm).transpose();
        cross += (q.coords - tm) * (p.coords - fm).transpose();
    }
    let a = cross * spread.try_inverse().unwrap();
    from.iter()
        .zip(to)
        .map(|(p, q)| (a * (p.coords - fm) + tm - q.coords).norm())
        .fold(0.0, Real::max)
}

fn similarity(scale: Real, angle: Real) -> Matrix2<Real> {
    nalgebra::Rotation2::new(angle).into_inner() * scale
}

#[test]
fn similarity_copies_of_a_symmetric_face_give_it_back() {
    // The reference structure is mirror symmetric to rounding, so its similar copies and their
    // mirrors are all similar to one frontal structure: the consensus is that structure.
    let truth = frontal_truth();
    let photos = vec![
        photo("a", &truth, similarity(3.0, 0.3), Vector2::new(300.0, -200.0)),
        photo("b", &truth, similarity(2.0, 0.0), Vector2::new(10.0, -20.0)),
        photo("c", &truth, similarity(1.2, -0.5), Vector2::new(-40.0, 70.0)),
    ];
    let frontal = procrustes_frontal(&photos).unwrap();
    assert_eq!(frontal.method, FrontalMethod::Procrustes);
    let error = max_distance(&frontal.points, &truth);
    assert!(error < 0.02, "max error {error}");
    assert!(frontal.residual_rms < 0.02, "residual {}", frontal.residual_rms);
    frontal.validate().unwrap();
    // The warps carry each photo onto the frontal structure.
    for (photo, warp) in photos.iter().zip(&frontal.warps) {
        let warped: Vec<_> = photo.y_up().iter().map(|p| apply_affine(warp, p)).collect();
        assert!(max_distance(&warped, &frontal.points) < 0.03);
    }
}

#[test]
fn affine_copies_give_an_affine_image_of_the_face() {
    // Points alone cannot tell a sheared or stretched face from a turned one: the consensus is
    // the face up to an affine map, and every photo maps onto it exactly.
    let truth = frontal_truth();
    let photos = vec![
        photo(
            "a",
            &truth,
            Matrix2::new(3.0, 0.4, -0.2, 2.5),
            Vector2::new(300.0, -200.0),
        ),
        photo(
            "b",
            &truth,
            Matrix2::new(2.0, 0.0, 0.0, 2.0),
            Vector2::new(10.0, -20.0),
        ),
        photo(
            "c",
            &truth,
            Matrix2::new(1.0, -0.5, 0.3, 1.6),
            Vector2::new(-40.0, 70.0),
        ),
    ];
    let frontal = procrustes_frontal(&photos).unwrap();
    assert!(affine_fit_error(&truth, &frontal.points) < 0.03);
    assert!(frontal.residual_rms < 0.02, "residual {}", frontal.residual_rms);
}

#[test]
fn a_lone_frontal_photo_gives_its_own_unified_points() {
    let truth = frontal_truth();
    let frontal = procrustes_frontal(&[photo(
        "front",
        &truth,
        Matrix2::identity() * 4.0,
        Vector2::new(320.0, -240.0),
    )])
    .unwrap();
    assert!(max_distance(&frontal.points, &truth) < 0.02);
    assert_eq!(frontal.warps.len(), 1);
    assert_eq!(frontal.mirror_warps.len(), 1);
}

#[test]
fn the_subjects_right_eye_stays_on_the_left_of_the_image() {
    // Catches a mirrored result: the outer corner of the subject's right eye (image left) must
    // come out at negative x.
    let truth = frontal_truth();
    let frontal = procrustes_frontal(&[photo(
        "front",
        &truth,
        Matrix2::new(2.0, 0.1, 0.0, 2.0),
        Vector2::new(0.0, 0.0),
    )])
    .unwrap();
    let outer = POINTS.iter().position(|d| d.name == "eye_right_outer").unwrap();
    assert!(frontal.points[outer].x < -30.0);
    let chin = POINTS.iter().position(|d| d.name == "contour_chin").unwrap();
    assert!(frontal.points[chin].y < -80.0, "y must point up");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// The span of `1, x, y` is affine invariant, so an affine change of any photo's points
    /// changes the consensus by an affine map at most.
    #[test]
    fn an_affine_change_of_one_photo_changes_the_result_by_an_affine_map_at_most(
        maps in prop::collection::vec(affine(), 2..6),
        change in affine(),
        which in 0usize..6,
        noise_seed in any::<u64>(),
    ) {
        let photos = noisy_photos(&maps, noise_seed);
        let before = procrustes_frontal(&photos).unwrap();
        let mut changed = photos.clone();
        let k = which % photos.len();
        let y_up = changed[k].y_up();
        changed[k] = photo("changed", &y_up, change.0, change.1);
        let after = procrustes_frontal(&changed).unwrap();
        let error = affine_fit_error(&before.points, &after.points);
        prop_assert!(error < 1e-6, "error {error}");
    }

    /// Mirroring every photo gives the same batch (each photo's mirror is already in it).
    #[test]
    fn mirroring_every_photo_changes_nothing(maps in prop::collection::vec(affine(), 1..5), noise_seed in any::<u64>()) {
        let photos = noisy_photos(&maps, noise_seed);
        let mirrored: Vec<PhotoPoints> = photos.iter().map(|p| {
            let pixels = POINTS.iter().map(|d| { let q = p.points[d.mirror]; Point2::new(1000.0 - q.x, q.y) }).collect();
            PhotoPoints::new(p.name.clone(), pixels).unwrap()
        }).collect();
        let a = procrustes_frontal(&photos).unwrap();
        let b = procrustes_frontal(&mirrored).unwrap();
        prop_assert!(max_distance(&a.points, &b.points) < 1e-7);
        // And the result is mirror symmetric: its mirror image is itself.
        let mirror: Vec<Point2<Real>> = POINTS.iter().map(|d| { let q = a.points[d.mirror]; Point2::new(-q.x, q.y) }).collect();
        prop_assert!(max_distance(&a.points, &mirror) < 1e-7);
    }
}

#[test]
fn bad_photos_are_errors_that_name_the_photo() {
    let truth = frontal_truth();
    let good = photo("good", &truth, Matrix2::identity(), Vector2::zeros());
    assert_eq!(procrustes_frontal(&[]), Err(AlignError::NoPhotos));

    let mut nan = good.points.clone();
    nan[7].y = f64::NAN;
    let error = PhotoPoints::new("nan.pts", nan.clone()).unwrap_err();
    assert_eq!(
        error,
        AlignError::Points {
            photo: "nan.pts".into(),
            source: StructureError::NonFinitePoint { index: 7 }
        }
    );
    assert!(error.to_string().contains("nan.pts"), "{error}");
    // Built by hand past the constructor: the stage checks again.
    let sneaked = PhotoPoints {
        name: "sneaked".into(),
        points: nan,
        inner_lips: Vec::new(),
    };
    assert!(
        matches!(procrustes_frontal(&[good.clone(), sneaked]), Err(AlignError::Points { photo, .. }) if photo == "sneaked")
    );

    let short = PhotoPoints::new("short", truth[..39].to_vec()).unwrap_err();
    assert!(
        short.to_string().contains("expected 40 points, got 39"),
        "{short}"
    );

    let mut same_eyes = good.points.clone();
    same_eyes[24] = same_eyes[23];
    assert!(matches!(
        PhotoPoints::new("eyes", same_eyes),
        Err(AlignError::Points {
            source: StructureError::CoincidentEyes,
            ..
        })
    ));

    // All points on one line (distinct eyes, so it passes the point checks).
    let line: Vec<Point2<Real>> = (0..40).map(|k| Point2::new(k as Real, 2.0 * k as Real)).collect();
    let flat = PhotoPoints::new("line", line).unwrap();
    assert_eq!(
        procrustes_frontal(&[good, flat]),
        Err(AlignError::Degenerate { photo: "line".into() })
    );
}

#[test]
fn photos_from_68_points_use_the_structure_derivation() {
    let ibug: Vec<Point2<Real>> = (0..68)
        .map(|i| Point2::new(i as Real, (i * i % 17) as Real))
        .collect();
    let p = PhotoPoints::from_ibug68("x.pts", &ibug).unwrap();
    assert_eq!(
        p.points[23],
        Point2::new(
            38.5,
            (0..6).map(|k| ((36 + k) * (36 + k) % 17) as Real).sum::<Real>() / 6.0
        )
    );
    let error = PhotoPoints::from_ibug68("few.pts", &ibug[..60]).unwrap_err();
    assert!(error.to_string().starts_with("photo few.pts:"), "{error}");
    // The inner lips ride along (iBUG 60–67), and give the gaps lower minus upper, y up.
    assert_eq!(p.inner_lips, ibug[60..68].to_vec());
    let gaps = p.lip_gaps_y_up().unwrap();
    for (gap, (upper, lower)) in gaps.iter().zip([(61, 67), (62, 66), (63, 65)]) {
        let d = ibug[lower] - ibug[upper];
        assert_eq!(*gap, nalgebra::Vector2::new(d.x, -d.y));
    }
    // 40 points alone have none; inner lips of another count or not finite are refused.
    let forty = PhotoPoints::new("forty.pts", p.points.clone()).unwrap();
    assert_eq!(forty.lip_gaps_y_up(), None);
    let short = PhotoPoints {
        inner_lips: ibug[60..67].to_vec(),
        ..p.clone()
    };
    let error = short.validate().unwrap_err();
    assert_eq!(
        error.to_string(),
        "photo x.pts: the inner lips (iBUG 60–67): 7 points, expected none or 8"
    );
    let mut nan = p.clone();
    nan.inner_lips[6].y = Real::NAN;
    assert_eq!(
        nan.validate().unwrap_err().to_string(),
        "photo x.pts: the inner lips (iBUG 60–67): point 66 is not finite"
    );
}
