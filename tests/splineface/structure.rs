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
