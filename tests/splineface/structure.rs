//! The 40-point structure: its table, the iBUG-68 conversion, mirroring.

use std::collections::HashSet;

use nalgebra::{Point2, Point3};
use proptest::prelude::*;
use splineface::structure::{
    Group, IBUG_POINT_COUNT, LEFT_EYE_CENTRE, POINT_COUNT, POINTS, RIGHT_EYE_CENTRE, StructureError,
    from_ibug68, mirrored_canonical, swap_partners,
};

/// The standard left–right partner of each iBUG-68 point (an oracle independent of the
/// structure table).
const IBUG_MIRROR: [usize; 68] = [
    16, 15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0, // jaw
    26, 25, 24, 23, 22, 21, 20, 19, 18, 17, // brows
    27, 28, 29, 30, // nose bridge
    35, 34, 33, 32, 31, // nose base
    45, 44, 43, 42, 47, 46, // right eye ↔ left eye
    39, 38, 37, 36, 41, 40, // left eye ↔ right eye
    54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55, // outer lips
    64, 63, 62, 61, 60, 67, 66, 65, // inner lips
];

#[test]
fn the_table_is_consistent() {
    assert_eq!(POINTS.len(), POINT_COUNT);
    let names: HashSet<_> = POINTS.iter().map(|p| p.name).collect();
    assert_eq!(names.len(), POINT_COUNT, "names are unique");
    for (k, p) in POINTS.iter().enumerate() {
        assert_eq!(POINTS[p.mirror].mirror, k, "mirroring {} twice", p.name);
        assert_eq!(
            POINTS[p.mirror].group, p.group,
            "partners of {} share a group",
            p.name
        );
        assert!(!p.ibug_sources.is_empty() && p.ibug_sources.iter().all(|&i| i < IBUG_POINT_COUNT));
        // A partner's sources are the mirror images of this point's sources.
        let mut mirrored: Vec<usize> = p.ibug_sources.iter().map(|&i| IBUG_MIRROR[i]).collect();
        let mut partner = POINTS[p.mirror].ibug_sources.to_vec();
        mirrored.sort();
        partner.sort();
        assert_eq!(mirrored, partner, "{}", p.name);
    }
    let count = |g: Group| POINTS.iter().filter(|p| p.group == g).count();
    assert_eq!(
        [
            count(Group::Contour),
            count(Group::Brows),
            count(Group::Eyes),
            count(Group::EyeCentres),
            count(Group::Nose),
            count(Group::Mouth)
        ],
        [9, 6, 8, 2, 7, 8]
    );
    assert_eq!(POINTS[RIGHT_EYE_CENTRE].ibug_sources, &[36, 37, 38, 39, 40, 41]);
    assert_eq!(POINTS[LEFT_EYE_CENTRE].mirror, RIGHT_EYE_CENTRE);
}

#[test]
fn conversion_matches_hand_worked_points() {
    // iBUG point i at (i, i²): means are easy to work by hand.
    let ibug: Vec<Point2<f64>> = (0..68).map(|i| Point2::new(i as f64, (i * i) as f64)).collect();
    let s = from_ibug68(&ibug).unwrap();
    assert_eq!(s[0], Point2::new(0.0, 0.0)); // contour_right_ear = iBUG 0
    assert_eq!(s[4], Point2::new(8.0, 64.0)); // chin = iBUG 8
    assert_eq!(s[12], Point2::new(22.0, 484.0)); // brow_left_inner = iBUG 22
    assert_eq!(s[16], Point2::new(37.5, (1369.0 + 1444.0) / 2.0)); // mean(37, 38)
    assert_eq!(s[22], Point2::new(46.5, (2116.0 + 2209.0) / 2.0)); // mean(46, 47)
    // mean(36..=41): x = 38.5, y = (1296 + 1369 + 1444 + 1521 + 1600 + 1681) / 6.
    assert_eq!(s[RIGHT_EYE_CENTRE].x, 38.5);
    assert!((s[RIGHT_EYE_CENTRE].y - 8911.0 / 6.0).abs() < 1e-12);
    assert_eq!(s[28], Point2::new(30.0, 900.0)); // nose_tip = iBUG 30
    assert_eq!(s[39], Point2::new(58.0, 3364.0)); // mouth_lower_right = iBUG 58
}

fn ibug_points() -> impl Strategy<Value = Vec<Point3<f64>>> {
    prop::collection::vec(prop::array::uniform3(-100.0..100.0f64), 68)
        .prop_map(|v| v.into_iter().map(|[x, y, z]| Point3::new(x, y, z)).collect())
}

proptest! {
    /// Converting a mirrored face equals mirroring the converted face.
    #[test]
    fn conversion_commutes_with_mirroring(ibug in ibug_points()) {
        let mirrored_ibug: Vec<Point3<f64>> =
            (0..68).map(|i| { let p = ibug[IBUG_MIRROR[i]]; Point3::new(-p.x, p.y, p.z) }).collect();
        let a = from_ibug68(&mirrored_ibug).unwrap();
        let b = mirrored_canonical(&from_ibug68(&ibug).unwrap()).unwrap();
        for (p, q) in a.iter().zip(&b) {
            prop_assert!((p - q).norm() < 1e-12);
        }
    }

    #[test]
    fn mirroring_twice_is_the_identity(ibug in ibug_points()) {
        let s = from_ibug68(&ibug).unwrap();
        prop_assert_eq!(&mirrored_canonical(&mirrored_canonical(&s).unwrap()).unwrap(), &s);
        prop_assert_eq!(&swap_partners(&swap_partners(&s).unwrap()).unwrap(), &s);
    }
}

#[test]
fn bad_point_sets_are_errors() {
    let short: Vec<Point2<f64>> = vec![Point2::origin(); 67];
    assert_eq!(
        from_ibug68(&short),
        Err(StructureError::WrongPointCount {
            got: 67,
            expected: 68
        })
    );
    let mut nan: Vec<Point2<f64>> = vec![Point2::origin(); 68];
    nan[12].y = f64::NAN;
    assert_eq!(
        from_ibug68(&nan),
        Err(StructureError::NonFinitePoint { index: 12 })
    );
    let forty: Vec<Point3<f64>> = vec![Point3::origin(); 41];
    assert!(matches!(
        mirrored_canonical(&forty),
        Err(StructureError::WrongPointCount { expected: 40, .. })
    ));
}

mod frame_and_similarity {
    use nalgebra::{
        Isometry2, Point2, Point3, Similarity2, Similarity3, Translation3, UnitQuaternion, Vector2, Vector3,
    };
    use proptest::prelude::*;
    use splineface::structure::{
        LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE, StructureError, delaunay_edges, edge_lengths,
        multi_substructure_similarity, ssim, substructures, unify, unify_2d,
    };

    use crate::common::Lcg;

    fn random_structure(seed: u64) -> Vec<Point3<f64>> {
        let mut rng = Lcg(seed);
        (0..40)
            .map(|_| rng.point_in([-60.0, -80.0, -10.0], [60.0, 40.0, 30.0]))
            .collect()
    }

    #[test]
    fn unify_puts_the_eye_centres_in_place_and_keeps_shape() {
        let s = random_structure(3);
        let (sim, u) = unify(&s).unwrap();
        assert!((u[RIGHT_EYE_CENTRE] - Point3::new(-25.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((u[LEFT_EYE_CENTRE] - Point3::new(25.0, 0.0, 0.0)).norm() < 1e-12);
        let scale = 50.0 / (s[LEFT_EYE_CENTRE] - s[RIGHT_EYE_CENTRE]).norm();
        assert!((sim.scaling() - scale).abs() < 1e-12);
        for (i, j) in [(0, 39), (5, 17), (28, 30)] {
            let ratio = (u[i] - u[j]).norm() / (s[i] - s[j]).norm();
            assert!((ratio - scale).abs() < 1e-12);
        }
    }

    #[test]
    fn unify_undoes_roll_yaw_scale_and_translation() {
        let (_, canonical) = unify(&random_structure(4)).unwrap();
        for rotation in [
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.4),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), -0.7),
        ] {
            let moved = Similarity3::from_parts(Translation3::new(3.0, -7.0, 11.0), rotation, 2.5);
            let s: Vec<Point3<f64>> = canonical.iter().map(|p| moved * p).collect();
            let (_, back) = unify(&s).unwrap();
            for (a, b) in back.iter().zip(&canonical) {
                assert!((a - b).norm() < 1e-10, "{a} vs {b}");
            }
        }
    }

    proptest! {
        #[test]
        fn unify_2d_is_invariant_under_similarities(angle in -3.1..3.1f64, scale in 0.1..10.0f64, tx in -100.0..100.0f64, ty in -100.0..100.0f64, seed in any::<u64>()) {
            let s: Vec<Point2<f64>> = random_structure(seed).iter().map(|p| p.xy()).collect();
            let moved = Similarity2::from_isometry(Isometry2::new(Vector2::new(tx, ty), angle), scale);
            let t: Vec<Point2<f64>> = s.iter().map(|p| moved * p).collect();
            let (_, a) = unify_2d(&s).unwrap();
            let (_, b) = unify_2d(&t).unwrap();
            for (p, q) in a.iter().zip(&b) {
                prop_assert!((p - q).norm() < 1e-8);
            }
            prop_assert!((a[LEFT_EYE_CENTRE] - Point2::new(25.0, 0.0)).norm() < 1e-12);
        }
    }

    #[test]
    fn coincident_eyes_are_an_error() {
        let mut s = random_structure(5);
        s[LEFT_EYE_CENTRE] = s[RIGHT_EYE_CENTRE];
        assert_eq!(unify(&s).unwrap_err(), StructureError::CoincidentEyes);
    }

    /// Convex hull vertex count by Andrew's monotone chain (independent of spade).
    fn hull_size(points: &[Point2<f64>]) -> usize {
        let mut p: Vec<Point2<f64>> = points.to_vec();
        p.sort_by(|a, b| {
            a.x.partial_cmp(&b.x)
                .unwrap()
                .then(a.y.partial_cmp(&b.y).unwrap())
        });
        let cross = |o: Point2<f64>, a: Point2<f64>, b: Point2<f64>| (a - o).perp(&(b - o));
        let mut hull: Vec<Point2<f64>> = Vec::new();
        for pass in 0..2 {
            let start = hull.len();
            let iter: Box<dyn Iterator<Item = &Point2<f64>>> = if pass == 0 {
                Box::new(p.iter())
            } else {
                Box::new(p.iter().rev())
            };
            for &q in iter {
                while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
                    hull.pop();
                }
                hull.push(q);
            }
            hull.pop();
        }
        hull.len()
    }

    #[test]
    fn delaunay_edges_satisfy_euler_and_substructures_partition_them() {
        for seed in 0..20 {
            let frontal: Vec<Point2<f64>> = random_structure(seed).iter().map(|p| p.xy()).collect();
            let edges = delaunay_edges(&frontal).unwrap();
            let h = hull_size(&frontal);
            assert_eq!(edges.len(), 3 * 40 - 3 - h, "Euler: E = 3n − 3 − h (seed {seed})");
            assert!(edges.windows(2).all(|w| w[0] < w[1]) && edges.iter().all(|&[a, b]| a < b && b < 40));
            let groups = substructures(&edges);
            assert_eq!(groups[0].len(), edges.len());
            // G2..G7 partition G1: every edge is in exactly one of them.
            let mut seen = vec![0; edges.len()];
            for g in &groups[1..] {
                for &k in g {
                    seen[k] += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "seed {seed}: {seen:?}");
        }
        let mut dup: Vec<Point2<f64>> = random_structure(1).iter().map(|p| p.xy()).collect();
        dup[7] = dup[3];
        assert_eq!(
            delaunay_edges(&dup),
            Err(StructureError::DuplicatePoint { first: 3, second: 7 })
        );
    }

    #[test]
    fn ssim_is_one_on_itself_and_drops_with_distortion() {
        let s = random_structure(9);
        let frontal: Vec<Point2<f64>> = s.iter().map(|p| p.xy()).collect();
        let edges = delaunay_edges(&frontal).unwrap();
        let groups = substructures(&edges);
        let reference = edge_lengths(&s, &edges);
        let range = reference.iter().copied().fold(0.0, f64::max);
        assert!((ssim(&reference, &reference, range) - 1.0).abs() < 1e-15);
        assert!((multi_substructure_similarity(&reference, &reference, &groups) - 1.0).abs() < 1e-15);
        let mut rng = Lcg(2);
        let noise: Vec<Vector3<f64>> = (0..40)
            .map(|_| {
                Vector3::new(
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                    rng.uniform(-1.0, 1.0),
                )
            })
            .collect();
        let mut last = (1.0, 1.0);
        for amplitude in [1.0, 3.0, 9.0] {
            let distorted: Vec<Point3<f64>> = s.iter().zip(&noise).map(|(p, n)| p + n * amplitude).collect();
            let lengths = edge_lengths(&distorted, &edges);
            let one = ssim(&reference, &lengths, range);
            let all = multi_substructure_similarity(&reference, &lengths, &groups);
            assert!(
                one < last.0 && all < last.1 && all > 0.0,
                "amplitude {amplitude}: {one} {all}"
            );
            assert!(
                (ssim(&lengths, &reference, range) - one).abs() < 1e-15,
                "symmetric"
            );
            last = (one, all);
        }
    }
}

#[test]
fn the_similarity_gradient_matches_finite_differences() {
    use splineface::structure::{
        edge_lengths, multi_substructure_similarity, multi_substructure_similarity_gradient, substructures,
    };
    let reference = splineface::reference::ReferenceFace::embedded();
    let edges = reference.edges();
    let groups = substructures(edges);
    let x = edge_lengths(reference.structure(), edges);
    let mut rng = crate::common::Lcg(5);
    let y: Vec<f64> = x.iter().map(|l| l * rng.uniform(0.7, 1.3)).collect();
    let mut gradient = vec![0.0; y.len()];
    let sim = multi_substructure_similarity_gradient(&x, &y, &groups, &mut gradient);
    assert!((sim - multi_substructure_similarity(&x, &y, &groups)).abs() < 1e-15);
    for e in 0..y.len() {
        let h = 1e-6;
        let (mut up, mut down) = (y.clone(), y.clone());
        up[e] += h;
        down[e] -= h;
        let numeric = (multi_substructure_similarity(&x, &up, &groups)
            - multi_substructure_similarity(&x, &down, &groups))
            / (2.0 * h);
        assert!(
            (numeric - gradient[e]).abs() < 1e-8 * (1.0 + numeric.abs()),
            "edge {e}: {numeric} vs {}",
            gradient[e]
        );
    }
}
