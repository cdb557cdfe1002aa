//! Landmark files: `.pts`, the JSON form and vertex-index lists.

use std::path::Path;

use nalgebra::{Point2, Point3};
use proptest::prelude::*;
use splineface::landmarks::{
    LandmarkPoints, LandmarkProblem, Landmarks, Scheme, format_landmarks_json, format_pts,
    parse_landmarks_json, parse_pts, parse_vertex_indices, read_landmarks_json, read_pts,
    read_vertex_indices,
};

use crate::common;

proptest! {
    #[test]
    fn pts_round_trip_is_exact(points in prop::collection::vec(prop::array::uniform2(any::<f64>().prop_filter("finite", |x| x.is_finite())), 0..80)) {
        let points: Vec<Point2<f64>> = points.into_iter().map(|[x, y]| Point2::new(x, y)).collect();
        let back = parse_pts(&format_pts(&points)).unwrap();
        prop_assert_eq!(back, points);
    }
}

#[test]
fn a_typical_pts_file_reads() {
    let text = "version: 1\r\nn_points:  3\r\n{\r\n10.5 20\r\n  -3 4e2\r\n0 0\r\n}\r\n\r\n";
    let p = parse_pts(text).unwrap();
    assert_eq!(
        p,
        vec![
            Point2::new(10.5, 20.0),
            Point2::new(-3.0, 400.0),
            Point2::new(0.0, 0.0)
        ]
    );
}

#[test]
fn malformed_pts_files_are_errors_with_a_line() {
    let cases: [(&str, &str); 10] = [
        ("version: 1\nn_points: 2\n{\n1 2\n", "ends after 1 of 2"),
        ("version: 1\nn_points: 2\n{\n1 2\n}\n", "1 points, expected 2"),
        (
            "version: 1\nn_points: 1\n{\n1 2\n3 4\n}\n",
            "line 5: more than the 1 points",
        ),
        (
            "version: 1\nn_points: 1\n{\nNaN 2\n}\n",
            "line 4: the value is not finite",
        ),
        (
            "version: 1\nn_points: 1\n{\n1 inf\n}\n",
            "line 4: the value is not finite",
        ),
        (
            "version: 1\nn_points: 1\n{\n1 x\n}\n",
            "line 4: `x` is not a number",
        ),
        ("version: 1\n{\n1 2\n}\n", "no n_points"),
        ("version: 1\nn_points: 1000000000000\n{\n", "above the limit"),
        (
            "version: 1\nn_points: 1\n{\n1 2\n}\nextra\n",
            "line 6: text after",
        ),
        ("", "no n_points"),
    ];
    for (text, needle) in cases {
        let message = parse_pts(text).expect_err(text).to_string();
        assert!(message.contains(needle), "{text:?}: {message}");
    }
}

#[test]
fn file_errors_name_the_file() {
    let message = read_pts(Path::new("/no/such/face.pts")).unwrap_err().to_string();
    assert!(
        message.starts_with("/no/such/face.pts: cannot read it"),
        "{message}"
    );
    let dir = std::env::temp_dir().join(format!("splineface-landmarks-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("bad.pts");
    std::fs::write(&file, "version: 1\nn_points: 1\n{\n1\n}\n").unwrap();
    let message = read_pts(&file).unwrap_err().to_string();
    assert!(
        message.contains("bad.pts") && message.contains("line 4"),
        "{message}"
    );
    // A directory where a file belongs.
    assert!(read_pts(&dir).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn vertex_index_lists_read_and_validate() {
    let text = "# header\n3\n\n  7 # trailing comment\n0\n";
    assert_eq!(parse_vertex_indices(text, 3, 8).unwrap(), vec![3, 7, 0]);
    assert!(matches!(
        parse_vertex_indices(text, 3, 7),
        Err(LandmarkProblem::IndexOutOfRange {
            line: 4,
            index: 7,
            vertices: 7
        })
    ));
    assert!(matches!(
        parse_vertex_indices(text, 4, 8),
        Err(LandmarkProblem::WrongCount { got: 3, expected: 4 })
    ));
    assert!(matches!(
        parse_vertex_indices(text, 2, 8),
        Err(LandmarkProblem::WrongCount { got: 3, expected: 2 })
    ));
    assert!(matches!(
        parse_vertex_indices("1\n-2\n", 2, 8),
        Err(LandmarkProblem::Syntax { line: 2, .. })
    ));
    assert!(matches!(
        parse_vertex_indices("1.5\n", 1, 8),
        Err(LandmarkProblem::Syntax { line: 1, .. })
    ));
}

#[test]
#[ignore = "needs ../shared/data/ict-face (not part of the repository)"]
fn the_ict_landmark_indices_read() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-face/landmarks68.txt");
    let indices = read_vertex_indices(&path, 68, 9409).unwrap();
    assert_eq!(indices.len(), 68);
    assert_eq!(indices[0], 1225);
    assert!(
        read_vertex_indices(&path, 68, 1000).is_err(),
        "indices above 1000 exist"
    );
}

fn json_with(points: &str, scheme: &str) -> String {
    format!(r#"{{"format": "splineface/landmarks", "version": 1, "scheme": "{scheme}", "points": {points}}}"#)
}

fn points_json(n: usize, dimension: usize) -> String {
    let point = |k: usize| {
        let c: Vec<String> = (0..dimension).map(|a| format!("{}.5", k * 3 + a)).collect();
        format!("[{}]", c.join(", "))
    };
    format!("[{}]", (0..n).map(point).collect::<Vec<_>>().join(", "))
}

#[test]
fn json_landmarks_read_both_schemes_and_dimensions() {
    let planar = parse_landmarks_json(&json_with(&points_json(68, 2), "ibug68")).unwrap();
    assert_eq!(planar.scheme, Scheme::Ibug68);
    let structure = planar.structure_2d().unwrap();
    assert_eq!(structure.len(), 40);
    // The right eye centre is the mean of iBUG 36..=41: x = 3k + 0.5 averaged over k = 36..=41.
    assert_eq!(structure[23], Point2::new(3.0 * 38.5 + 0.5, 3.0 * 38.5 + 1.5));
    assert!(matches!(
        planar.structure_3d(),
        Err(LandmarkProblem::Dimension { got: 2, expected: 3 })
    ));
    let spatial = parse_landmarks_json(&json_with(&points_json(40, 3), "structure40")).unwrap();
    let points = spatial.structure_3d().unwrap();
    assert_eq!(points[39], Point3::new(117.5, 118.5, 119.5));
}

#[test]
fn json_landmarks_round_trip_exactly() {
    let mut rng = common::Lcg(5);
    let points: Vec<Point3<f64>> = (0..68)
        .map(|_| Point3::new(rng.uniform(-1e3, 1e3), rng.next() * 1e-7, rng.uniform(-3.0, 3.0)))
        .collect();
    let landmarks = Landmarks {
        scheme: Scheme::Ibug68,
        points: LandmarkPoints::Spatial(points),
    };
    let text = format_landmarks_json(&landmarks).unwrap();
    assert_eq!(parse_landmarks_json(&text).unwrap(), landmarks);
}

#[test]
fn json_landmarks_reject_malformed_input() {
    let cases = [
        (json_with(&points_json(67, 2), "ibug68"), "67 points, expected 68"),
        (
            json_with(&points_json(68, 2), "structure40"),
            "68 points, expected 40",
        ),
        (
            json_with(&points_json(40, 4), "structure40"),
            "the points have 4 coordinates each, expected 2 or 3",
        ),
        (
            json_with("[[1, 2], [1, 2, 3]]", "structure40"),
            "2 points, expected 40",
        ),
        (
            json_with(&points_json(40, 2), "mediapipe"),
            "unknown variant `mediapipe`",
        ),
        (
            json_with(&points_json(40, 2), "structure40").replace("\"version\": 1", "\"version\": 2"),
            "version 2",
        ),
        (
            json_with(&points_json(40, 2), "structure40").replace("splineface/landmarks", "x"),
            "format is \"x\"",
        ),
        (
            json_with(&points_json(40, 2), "structure40").replace("\"version\"", "\"extra\": 0, \"version\""),
            "unknown field `extra`",
        ),
        (json_with("[[1, 1e999]]", "structure40"), "line 1"),
        ("{".to_owned(), "line 1"),
    ];
    for (text, expected) in cases {
        let message = parse_landmarks_json(&text).unwrap_err().to_string();
        assert!(
            message.contains(expected),
            "{text}: got {message:?}, expected {expected:?}"
        );
    }
    let mut mixed: Vec<String> = (0..40).map(|k| format!("[{k}, 1]")).collect();
    mixed[7] = "[7, 1, 2]".into();
    let message = parse_landmarks_json(&json_with(&format!("[{}]", mixed.join(",")), "structure40"))
        .unwrap_err()
        .to_string();
    assert_eq!(message, "point 7 has 3 coordinates, the first has 2");
    // Written landmarks must hold finite points.
    let mut points = vec![Point2::new(0.0, 0.0); 40];
    points[3].y = f64::NAN;
    let bad = Landmarks {
        scheme: Scheme::Structure40,
        points: LandmarkPoints::Planar(points),
    };
    assert!(matches!(
        format_landmarks_json(&bad),
        Err(LandmarkProblem::NonFinitePoint { point: 3 })
    ));
    assert!(matches!(
        bad.structure_2d(),
        Err(LandmarkProblem::NonFinitePoint { point: 3 })
    ));
}

#[test]
fn json_landmark_file_errors_name_the_file() {
    let path = std::env::temp_dir().join(format!("splineface-landmarks-{}.json", std::process::id()));
    std::fs::write(&path, json_with(&points_json(3, 2), "ibug68")).unwrap();
    let message = read_landmarks_json(&path).unwrap_err().to_string();
    assert!(
        message.starts_with(&path.display().to_string()) && message.ends_with("3 points, expected 68"),
        "{message}"
    );
}
